//! The shared secret a robot's hello carries and a RobotServer checks: from `--token` or the
//! environment, for `serve` and `robot` alike.

/// The shared secret from the environment when no `--token` is given (keeps it out of the
/// process list).
pub const TOKEN_ENV: &str = "TWINBOTS_TOKEN";

/// `--token`'s value: refused when empty (`--token "$UNSET"` would otherwise switch the
/// authentication off, silently).
pub fn non_empty(value: &str) -> Result<String, String> {
    if value.is_empty() {
        return Err("an empty token is refused (an unset variable?); leave --token out for no token".into());
    }
    Ok(value.to_string())
}

/// The token of `$TWINBOTS_TOKEN`; an empty one counts as unset.
pub fn from_env() -> Option<String> {
    std::env::var(TOKEN_ENV).ok().filter(|t| !t.is_empty())
}
