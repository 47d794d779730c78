//! Columns of a Parquet file as Apache Arrow writes them (pyarrow, pandas, Hugging Face
//! `datasets`): every field nullable, lists in the three-level `LIST` layout, strings as UTF-8
//! byte arrays, so that what Arrow reads back is what its own writer would have written.

use std::path::Path;
use std::sync::Arc;

use parquet::basic::{Compression, LogicalType, Repetition, Type as PhysicalType};
use parquet::data_type::{BoolType, ByteArray, ByteArrayType, DoubleType, FloatType, Int64Type};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::WriterProperties;
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::Type;

/// One column's values, one entry (or one list) per row.
#[derive(Clone, Debug, PartialEq)]
pub enum Column {
    F32(Vec<f32>),
    I64(Vec<i64>),
    Bool(Vec<bool>),
    Str(Vec<String>),
    /// Rows of `width` values each, row-major: Arrow's `list<float>` (LeRobot's
    /// `Sequence(length=width)`).
    F32Rows {
        width: usize,
        values: Vec<f32>,
    },
    F64Lists(Vec<Vec<f64>>),
    /// Rows of per-channel values, each row as NumPy's `(channels, 1, 1)` array becomes Arrow's
    /// `list<list<list<double>>>` (LeRobot's image statistics per episode).
    F64Channels(Vec<Vec<f64>>),
    /// Encoded images (PNG), one per row: Hugging Face `datasets`' `Image()` feature, Arrow's
    /// `struct<bytes: binary, path: string>`, the path a name for the file it would have been.
    Images {
        png: Vec<Vec<u8>>,
        paths: Vec<String>,
    },
    BoolLists(Vec<Vec<bool>>),
    I64Lists(Vec<Vec<i64>>),
    StrLists(Vec<Vec<String>>),
}

impl Column {
    /// Its number of rows.
    pub fn rows(&self) -> usize {
        match self {
            Column::F32(v) => v.len(),
            Column::I64(v) => v.len(),
            Column::Bool(v) => v.len(),
            Column::Str(v) => v.len(),
            Column::F32Rows { width, values } => values.len() / (*width).max(1),
            Column::F64Lists(v) => v.len(),
            Column::F64Channels(v) => v.len(),
            Column::Images { png, .. } => png.len(),
            Column::BoolLists(v) => v.len(),
            Column::I64Lists(v) => v.len(),
            Column::StrLists(v) => v.len(),
        }
    }

    fn field(&self, name: &str) -> parquet::errors::Result<Type> {
        let leaf = |name: &str, physical: PhysicalType, logical: Option<LogicalType>| {
            Type::primitive_type_builder(name, physical)
                .with_repetition(Repetition::OPTIONAL)
                .with_logical_type(logical)
                .build()
        };
        let list_of = |name: &str, element: Type| -> parquet::errors::Result<Type> {
            let repeated = Type::group_type_builder("list")
                .with_repetition(Repetition::REPEATED)
                .with_fields(vec![Arc::new(element)])
                .build()?;
            Type::group_type_builder(name)
                .with_repetition(Repetition::OPTIONAL)
                .with_logical_type(Some(LogicalType::List))
                .with_fields(vec![Arc::new(repeated)])
                .build()
        };
        let list = |physical: PhysicalType, logical: Option<LogicalType>| -> parquet::errors::Result<Type> {
            list_of(name, leaf("element", physical, logical)?)
        };
        match self {
            Column::F32(_) => leaf(name, PhysicalType::FLOAT, None),
            Column::I64(_) => leaf(name, PhysicalType::INT64, None),
            Column::Bool(_) => leaf(name, PhysicalType::BOOLEAN, None),
            Column::Str(_) => leaf(name, PhysicalType::BYTE_ARRAY, Some(LogicalType::String)),
            Column::F32Rows { .. } => list(PhysicalType::FLOAT, None),
            Column::F64Lists(_) => list(PhysicalType::DOUBLE, None),
            Column::F64Channels(_) => {
                let inner = list_of("element", leaf("element", PhysicalType::DOUBLE, None)?)?;
                list_of(name, list_of("element", inner)?)
            }
            Column::Images { .. } => Type::group_type_builder(name)
                .with_repetition(Repetition::OPTIONAL)
                .with_fields(vec![
                    Arc::new(leaf("bytes", PhysicalType::BYTE_ARRAY, None)?),
                    Arc::new(leaf("path", PhysicalType::BYTE_ARRAY, Some(LogicalType::String))?),
                ])
                .build(),
            Column::BoolLists(_) => list(PhysicalType::BOOLEAN, None),
            Column::I64Lists(_) => list(PhysicalType::INT64, None),
            Column::StrLists(_) => list(PhysicalType::BYTE_ARRAY, Some(LogicalType::String)),
        }
    }
}

/// Repetition and definition levels of list rows of these lengths, every element present
/// (definition 3: the list, its repeated group and the element defined; an empty list: 1).
fn list_levels(lengths: impl Iterator<Item = usize>) -> (Vec<i16>, Vec<i16>) {
    let (mut def, mut rep) = (Vec::new(), Vec::new());
    for n in lengths {
        if n == 0 {
            def.push(1);
            rep.push(0);
        }
        for k in 0..n {
            def.push(3);
            rep.push(i16::from(k > 0));
        }
    }
    (def, rep)
}

/// A table: named columns of equal length, and the file's key-value metadata.
#[derive(Clone, Debug, Default)]
pub struct Table {
    pub columns: Vec<(String, Column)>,
    pub metadata: Vec<(String, String)>,
}

impl Table {
    pub fn push(&mut self, name: impl Into<String>, column: Column) {
        self.columns.push((name.into(), column));
    }

    /// Writes the table as one row group of a Snappy-compressed Parquet file at `path`.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let rows = self.columns.first().map_or(0, |(_, c)| c.rows());
        for (name, column) in &self.columns {
            anyhow::ensure!(column.rows() == rows, "column {name} has {} rows, not {rows}", column.rows());
        }
        let fields = self
            .columns
            .iter()
            .map(|(name, c)| c.field(name).map(Arc::new))
            .collect::<parquet::errors::Result<Vec<_>>>()?;
        let schema = Arc::new(Type::group_type_builder("schema").with_fields(fields).build()?);
        let metadata = self.metadata.iter().map(|(k, v)| KeyValue::new(k.clone(), v.clone())).collect::<Vec<_>>();
        let properties = WriterProperties::builder()
            .set_compression(Compression::SNAPPY)
            .set_created_by(format!("twinbots {}", env!("CARGO_PKG_VERSION")))
            .set_key_value_metadata((!metadata.is_empty()).then_some(metadata))
            .build();
        let file = std::fs::File::create(path)?;
        let mut writer = SerializedFileWriter::new(file, schema, Arc::new(properties))?;
        let mut group = writer.next_row_group()?;
        for (_, column) in &self.columns {
            if let Column::Images { png, paths } = column {
                // The struct and its field both present: definition level 2, in two leaf columns.
                let present = vec![2i16; png.len()];
                let mut out = next_column(&mut group)?;
                let bytes: Vec<ByteArray> = png.iter().map(|b| ByteArray::from(b.clone())).collect();
                out.typed::<ByteArrayType>().write_batch(&bytes, Some(&present), None)?;
                out.close()?;
                let mut out = next_column(&mut group)?;
                let paths: Vec<ByteArray> = paths.iter().map(|p| ByteArray::from(p.as_str())).collect();
                out.typed::<ByteArrayType>().write_batch(&paths, Some(&present), None)?;
                out.close()?;
                continue;
            }
            let mut out = next_column(&mut group)?;
            let present = vec![1i16; column.rows()];
            match column {
                Column::F32(v) => {
                    out.typed::<FloatType>().write_batch(v, Some(&present), None)?;
                }
                Column::I64(v) => {
                    out.typed::<Int64Type>().write_batch(v, Some(&present), None)?;
                }
                Column::Bool(v) => {
                    out.typed::<BoolType>().write_batch(v, Some(&present), None)?;
                }
                Column::Str(v) => {
                    let bytes: Vec<ByteArray> = v.iter().map(|s| ByteArray::from(s.as_str())).collect();
                    out.typed::<ByteArrayType>().write_batch(&bytes, Some(&present), None)?;
                }
                Column::F32Rows { width, values } => {
                    let (def, rep) = list_levels(std::iter::repeat_n(*width, column.rows()));
                    out.typed::<FloatType>().write_batch(values, Some(&def), Some(&rep))?;
                }
                Column::F64Lists(v) => {
                    let (def, rep) = list_levels(v.iter().map(Vec::len));
                    out.typed::<DoubleType>().write_batch(&v.concat(), Some(&def), Some(&rep))?;
                }
                Column::F64Channels(v) => {
                    // Three nested lists, the inner two of one element: a value starts a new
                    // element of the outer list (repetition 1) but the row's first (0); every
                    // level present (definition 7: three lists, three repeated groups, the value).
                    let (mut def, mut rep) = (Vec::new(), Vec::new());
                    for row in v {
                        if row.is_empty() {
                            def.push(1);
                            rep.push(0);
                        }
                        for k in 0..row.len() {
                            def.push(7);
                            rep.push(i16::from(k > 0));
                        }
                    }
                    out.typed::<DoubleType>().write_batch(&v.concat(), Some(&def), Some(&rep))?;
                }
                Column::Images { .. } => unreachable!("written above"),
                Column::BoolLists(v) => {
                    let (def, rep) = list_levels(v.iter().map(Vec::len));
                    out.typed::<BoolType>().write_batch(&v.concat(), Some(&def), Some(&rep))?;
                }
                Column::I64Lists(v) => {
                    let (def, rep) = list_levels(v.iter().map(Vec::len));
                    out.typed::<Int64Type>().write_batch(&v.concat(), Some(&def), Some(&rep))?;
                }
                Column::StrLists(v) => {
                    let (def, rep) = list_levels(v.iter().map(Vec::len));
                    let bytes: Vec<ByteArray> = v.iter().flatten().map(|s| ByteArray::from(s.as_str())).collect();
                    out.typed::<ByteArrayType>().write_batch(&bytes, Some(&def), Some(&rep))?;
                }
            }
            out.close()?;
        }
        group.close()?;
        writer.close()?;
        Ok(())
    }
}

fn next_column<'a, W: std::io::Write + Send>(
    group: &'a mut parquet::file::writer::SerializedRowGroupWriter<'_, W>,
) -> anyhow::Result<parquet::file::writer::SerializedColumnWriter<'a>> {
    group.next_column()?.ok_or_else(|| anyhow::anyhow!("the schema has fewer columns"))
}
