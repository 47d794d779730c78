//! How deep XML nests, found by a scan of its tags before any parser recurses into it.

/// How deep XML elements may nest: a URDF is a handful of levels, a Collada scene a few dozen;
/// 20,000 overflowed the stack of the parsers behind it.
pub const MAX_XML_DEPTH: usize = 256;

/// The line at which `text`'s elements nest deeper than [`MAX_XML_DEPTH`], if they do. A scan
/// of the tags alone (comments, CDATA and declarations skipped), before any parser recurses.
pub(crate) fn too_deep(text: &str) -> Option<usize> {
    let bytes = text.as_bytes();
    let (mut depth, mut line, mut i) = (0usize, 1usize, 0usize);
    let skip_to = |from: usize, end: &str| text[from..].find(end).map_or(bytes.len(), |k| from + k + end.len());
    while i < bytes.len() {
        match bytes[i] {
            b'\n' => {
                line += 1;
                i += 1;
            }
            b'<' if text[i..].starts_with("<!--") => i = skip_to(i, "-->"),
            b'<' if text[i..].starts_with("<![CDATA[") => i = skip_to(i, "]]>"),
            b'<' if matches!(bytes.get(i + 1), Some(b'!' | b'?')) => i = skip_to(i, ">"),
            b'<' if bytes.get(i + 1) == Some(&b'/') => {
                depth = depth.saturating_sub(1);
                i += 2;
            }
            b'<' => {
                // To the tag's end, past quoted attribute values.
                let mut j = i + 1;
                let mut quote = None;
                while j < bytes.len() {
                    match (bytes[j], quote) {
                        (b'"' | b'\'', None) => quote = Some(bytes[j]),
                        (q, Some(open)) if q == open => quote = None,
                        (b'>', None) => break,
                        (b'\n', _) => line += 1,
                        _ => {}
                    }
                    j += 1;
                }
                if bytes.get(j.saturating_sub(1)) != Some(&b'/') {
                    depth += 1;
                    if depth > MAX_XML_DEPTH {
                        return Some(line);
                    }
                }
                i = j + 1;
            }
            _ => i += 1,
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comments_cdata_quotes_and_empty_tags_are_no_levels() {
        let fine = "<?xml version=\"1.0\"?>\n<!-- <a><a> -->\n<robot name=\"r\" note=\"a > b\"><![CDATA[<x><x>]]><link name=\"a\"/></robot>";
        assert_eq!(too_deep(fine), None);
        assert_eq!(too_deep(&format!("{}{}", "<a>".repeat(256), "</a>".repeat(256))), None);
        assert_eq!(too_deep(&"<a>".repeat(257)), Some(1));
    }

    /// Elements nested 20,000 deep overflowed the parsers' stacks (the process aborted): the
    /// depth is checked first, and the error names the file and the line.
    #[test]
    fn xml_nested_too_deep_is_an_error_not_a_crash() {
        let deep = format!(
            "<robot name=\"deep\">\n{}{}<link name=\"a\"/></robot>",
            "<x>".repeat(20_000),
            "</x>".repeat(20_000)
        );
        let err =
            super::super::load::parse_urdf_exact(&deep, std::path::Path::new("deep.urdf")).unwrap_err().to_string();
        assert!(err.starts_with("deep.urdf:2:1: malformed XML: elements nest deeper than 256 levels"), "{err}");
    }
}
