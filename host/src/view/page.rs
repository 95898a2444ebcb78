//! The page's assets, built into the binary: no file or network access at
//! run time. Plain HTML, CSS and canvas drawing, no library.

const INDEX: &str = include_str!("page/index.html");
const SCRIPT: &str = include_str!("page/view.js");
const STYLE: &str = include_str!("page/view.css");

/// The content type and body of the asset at `path`, if there is one.
pub fn asset(path: &str) -> Option<(&'static str, &'static [u8])> {
    match path {
        "/" | "/index.html" => Some(("text/html; charset=utf-8", INDEX.as_bytes())),
        "/view.js" => Some(("text/javascript; charset=utf-8", SCRIPT.as_bytes())),
        "/view.css" => Some(("text/css; charset=utf-8", STYLE.as_bytes())),
        _ => None,
    }
}
