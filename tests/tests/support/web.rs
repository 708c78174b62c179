//! What the web tests need besides the binary: `node`, the npm packages that `scripts/setup`
//! installs (`INSSPLAT_WEB_DIR`) and, for the page, Debian's `chromium`. Outside CI a test
//! without them skips, saying what is missing; under `CI=true` it fails instead.

use std::path::PathBuf;

/// `name` found on PATH.
pub fn program(name: &str) -> Result<PathBuf, String> {
    std::env::var_os("PATH")
        .and_then(|paths| std::env::split_paths(&paths).map(|d| d.join(name)).find(|p| p.is_file()))
        .ok_or_else(|| format!("`{name}` is not on PATH"))
}

/// The npm packages' node_modules folder, checked to hold `package` (e.g. `playwright-core`).
pub fn npm_package(package: &str) -> Result<PathBuf, String> {
    let dir = std::env::var_os("INSSPLAT_WEB_DIR")
        .map(PathBuf::from)
        .ok_or("INSSPLAT_WEB_DIR is not set (source .deps/env)")?;
    if dir.join(package).join("package.json").is_file() {
        Ok(dir)
    } else {
        Err(format!("npm package {package} is missing from {}", dir.display()))
    }
}

/// `what` when there; else None after saying why the test skips, or a panic under CI=true.
pub fn require<T>(what: Result<T, String>) -> Option<T> {
    match what {
        Ok(t) => Some(t),
        Err(why) if std::env::var("CI").as_deref() != Ok("true") => {
            eprintln!("SKIPPED: {why}; scripts/setup installs it");
            None
        }
        Err(why) => panic!("{why}: under CI=true this test must run (scripts/setup installs it)"),
    }
}
