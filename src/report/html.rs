//! A minimal HTML writer for self-contained reports: escaped text, tables,
//! pass/warn marks and images inlined as base64 PNG.

use std::fmt::Write;
use std::path::Path;

use base64::Engine;

use crate::error::{Error, Result};
use crate::store::status::CALIBRATION_ID_META;

/// The name of a report in its folder.
pub const REPORT: &str = crate::store::status::REPORT;

/// Escapes text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// A verdict shown as a coloured mark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mark {
    Pass,
    Warn,
}

impl Mark {
    pub fn of(ok: bool) -> Mark {
        if ok {
            Mark::Pass
        } else {
            Mark::Warn
        }
    }
    pub fn html(self) -> &'static str {
        match self {
            Mark::Pass => "<span class=\"pass\">✔ pass</span>",
            Mark::Warn => "<span class=\"warn\">⚠ warn</span>",
        }
    }
}

/// A page under construction.
pub struct Page {
    title: String,
    nav: Vec<(String, String)>,
    body: String,
    derived_from: Vec<String>,
}

const STYLE: &str = "body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:1180px;margin:2em auto;padding:0 1em;color:#1b1b1b;line-height:1.45}\
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:2px solid #0072b2;padding-bottom:.15em;margin-top:2em}\
table{border-collapse:collapse;margin:.6em 0 1em;font-size:.92em}th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}\
th{background:#eef4fa}td:first-child,th:first-child{text-align:left}\
.pass{color:#007a4d;font-weight:600}.warn{color:#b35900;font-weight:600}\
figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.9em;color:#444}\
nav a{margin-right:1em}pre{background:#f6f6f6;padding:.8em;overflow-x:auto;font-size:.85em}\
.note{background:#fff8e5;border-left:4px solid #e69f00;padding:.5em .8em}.muted{color:#666}";

impl Page {
    pub fn new(title: &str) -> Page {
        Page {
            title: title.to_string(),
            nav: Vec::new(),
            body: String::new(),
            derived_from: Vec::new(),
        }
    }

    /// Names a calibration the page was made from (a `mrbp-calibration-id`
    /// meta tag: `mrbp status` checks it against the folder's calibration).
    pub fn derived_from(&mut self, calibration_id: &str) {
        self.derived_from.push(calibration_id.to_string());
    }

    /// Starts a section with an anchor listed in the navigation bar.
    pub fn section(&mut self, id: &str, heading: &str) {
        self.nav.push((id.to_string(), heading.to_string()));
        let _ = writeln!(self.body, "<h2 id=\"{}\">{}</h2>", esc(id), esc(heading));
    }

    /// A paragraph of escaped text.
    pub fn para(&mut self, text: &str) {
        let _ = writeln!(self.body, "<p>{}</p>", esc(text));
    }

    /// Raw HTML the caller has built (and escaped) itself.
    pub fn raw(&mut self, html: &str) {
        self.body.push_str(html);
        self.body.push('\n');
    }

    pub fn note(&mut self, text: &str) {
        let _ = writeln!(self.body, "<p class=\"note\">{}</p>", esc(text));
    }

    pub fn pre(&mut self, text: &str) {
        let _ = writeln!(self.body, "<pre>{}</pre>", esc(text));
    }

    /// A table; cells are raw HTML (escape text with [`esc`]).
    pub fn table(&mut self, header: &[&str], rows: &[Vec<String>]) {
        self.body.push_str("<table><thead><tr>");
        for h in header {
            let _ = write!(self.body, "<th>{}</th>", esc(h));
        }
        self.body.push_str("</tr></thead><tbody>\n");
        for row in rows {
            self.body.push_str("<tr>");
            for c in row {
                let _ = write!(self.body, "<td>{c}</td>");
            }
            self.body.push_str("</tr>\n");
        }
        self.body.push_str("</tbody></table>\n");
    }

    /// A PNG file inlined as a data URI, with its caption.
    pub fn figure(&mut self, png: &Path, caption: &str) -> Result<()> {
        let bytes = std::fs::read(png)
            .map_err(|e| Error::input(png, format!("cannot read figure: {e}")))?;
        let data = base64::engine::general_purpose::STANDARD.encode(bytes);
        let alt = png.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let _ = writeln!(
            self.body,
            "<figure><img alt=\"{}\" src=\"data:image/png;base64,{data}\"><figcaption>{}</figcaption></figure>",
            esc(&alt),
            esc(caption)
        );
        Ok(())
    }

    pub fn finish(self) -> String {
        let mut html = String::new();
        let _ = write!(
            html,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
             <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">{}\
             <title>{}</title><style>{STYLE}</style></head><body>\n<h1>{}</h1>\n<nav>",
            self.derived_from
                .iter()
                .map(|id| format!("<meta name=\"{CALIBRATION_ID_META}\" content=\"{}\">", esc(id)))
                .collect::<String>(),
            esc(&self.title),
            esc(&self.title)
        );
        for (id, heading) in &self.nav {
            let _ = write!(html, "<a href=\"#{}\">{}</a>", esc(id), esc(heading));
        }
        html.push_str("</nav>\n");
        html.push_str(&self.body);
        html.push_str("</body></html>\n");
        html
    }
}

/// A number with `digits` significant digits, in scientific notation
/// outside [1e-3, 1e5).
pub fn num(v: f64, digits: usize) -> String {
    if !v.is_finite() {
        return "–".into();
    }
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{:.*e}", digits.saturating_sub(1), v)
    } else {
        let decimals = if a == 0.0 {
            0
        } else {
            (digits as i32 - 1 - a.log10().floor() as i32).max(0) as usize
        };
        format!("{v:.decimals$}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_numbers_are_short() {
        assert_eq!(esc("a<b & \"c\""), "a&lt;b &amp; &quot;c&quot;");
        assert_eq!(num(123456.0, 3), "1.23e5");
        assert_eq!(num(0.012345, 3), "0.0123");
        assert_eq!(num(1.0, 3), "1.00");
        assert_eq!(num(f64::NAN, 3), "–");
    }

    #[test]
    fn page_lists_its_sections() {
        let mut p = Page::new("t");
        p.section("a", "Alpha");
        p.table(&["x", "y"], &[vec!["1".into(), Mark::Pass.html().into()]]);
        let html = p.finish();
        assert!(
            html.contains("href=\"#a\"")
                && html.contains("<h2 id=\"a\">Alpha</h2>")
                && html.contains("✔ pass")
        );
    }
}
