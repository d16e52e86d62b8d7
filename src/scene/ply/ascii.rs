//! The ascii PLY body: one record per non-blank line, values checked against their types and
//! counts so that a file whose data does not match its header is reported, not misread.

use super::header::{Element, Header, Kind, Property, Role, Scalar};
use super::{Builder, Line, read_line, snippet};
use crate::error::{Error, Result};
use std::io::BufRead;
use std::path::Path;

/// Longest ascii data line accepted (a polygon of a few hundred thousand vertices).
const MAX_DATA_LINE: u64 = 1 << 22;

impl Scalar {
    /// Parses an ascii value. Integers must be integers in range of their type, so that a line of
    /// one element misread as another (a count mismatch) fails here rather than later.
    fn parse_text(self, tok: &str) -> std::result::Result<f64, String> {
        match self {
            // Parsing as f32 directly avoids double rounding through f64.
            Self::F32 => tok.parse::<f32>().map(f64::from),
            Self::F64 => tok.parse::<f64>(),
            _ => {
                let v: i64 = tok
                    .parse()
                    .map_err(|_| format!("expected an integer, found '{}'", snippet(tok)))?;
                let (lo, hi) = self.int_range();
                return if (lo..=hi).contains(&v) {
                    Ok(v as f64)
                } else {
                    Err(format!("value {v} out of range for {}", self.name()))
                };
            }
        }
        .map_err(|_| format!("expected a number, found '{}'", snippet(tok)))
    }
}

pub(super) fn read_ascii<R: BufRead>(
    r: &mut R,
    header: &Header,
    b: &mut Builder,
    origin: &Path,
) -> Result<()> {
    let mut line_no = header.lines;
    let mut buf = Vec::new();
    for el in &header.elements {
        // A record without properties has no values, hence no line to read.
        if el.props.is_empty() {
            continue;
        }
        for i in 0..el.count {
            // Next non-blank line.
            loop {
                let got =
                    read_line(r, &mut buf, MAX_DATA_LINE).map_err(|e| Error::io(origin, e))?;
                let place = || Some(format!("{} {i} (line {})", el.name, line_no + 1));
                match got {
                    Line::Eof => {
                        let msg = format!("file ends after {i} of {} {}", el.count, el.plural());
                        return Err(Error::format(origin, Some(format!("{} {i}", el.name)), msg));
                    }
                    Line::TooLong => {
                        let msg = format!("line is longer than {MAX_DATA_LINE} bytes");
                        return Err(Error::format(origin, place(), msg));
                    }
                    Line::Text => {}
                }
                line_no += 1;
                if !buf.iter().all(u8::is_ascii_whitespace) {
                    break;
                }
            }
            let at = |msg: String| {
                Error::format(
                    origin,
                    Some(format!("{} {i} (line {line_no})", el.name)),
                    msg,
                )
            };
            let text =
                std::str::from_utf8(&buf).map_err(|_| at("line is not valid UTF-8 text".into()))?;
            ascii_record(text, el, b).map_err(at)?;
            b.finish(el.target).map_err(at)?;
        }
    }
    let mut extra = 0u64;
    let mut first = 0;
    loop {
        match read_line(r, &mut buf, MAX_DATA_LINE).map_err(|e| Error::io(origin, e))? {
            Line::Eof => break,
            Line::Text | Line::TooLong => {}
        }
        // A line cut at the length cap is counted again as its continuation; close enough.
        line_no += 1;
        if !buf.iter().all(u8::is_ascii_whitespace) {
            if extra == 0 {
                first = line_no;
            }
            extra += 1;
        }
    }
    if extra > 0 {
        let lines = if extra == 1 { "line" } else { "lines" };
        return Err(Error::format(
            origin,
            Some(format!("line {first}")),
            format!("{extra} {lines} of data after the last element"),
        ));
    }
    Ok(())
}

/// Parses one ascii record; each record must be exactly one line.
fn ascii_record(text: &str, el: &Element, b: &mut Builder) -> std::result::Result<(), String> {
    let mut tokens = text.split_ascii_whitespace();
    // Without lists the number of values is known: check it first, since a wrong count says
    // "this line belongs to another element" better than the first value that fails to parse.
    if el.fixed_size().is_some() {
        let found = tokens.clone().count();
        if found != el.props.len() {
            let more = if found > el.props.len() {
                "many"
            } else {
                "few"
            };
            return Err(format!(
                "too {more} values for element '{}': expected {}, found {found}",
                el.name,
                el.props.len()
            ));
        }
    }
    let mut used = 0usize;
    let mut next = |p: &Property| {
        let tok = tokens.next().ok_or_else(|| {
            format!(
                "too few values for element '{}': line ends after {used}, before '{}'",
                el.name, p.name
            )
        })?;
        used += 1;
        Ok::<_, String>(tok)
    };
    for p in &el.props {
        match p.kind {
            Kind::Scalar(t) => {
                let v = t.parse_text(next(p)?)?;
                b.scalar(p.role, v);
            }
            Kind::List { count, item } => {
                let n = count.parse_text(next(p)?)?;
                if n < 0.0 {
                    return Err(format!("list '{}' has negative length {n}", p.name));
                }
                for _ in 0..n as u64 {
                    let v = item.parse_text(next(p)?)?;
                    if p.role == Role::Indices {
                        b.index(v)?;
                    }
                }
            }
        }
    }
    let rest = tokens.count();
    if rest > 0 {
        return Err(format!(
            "too many values for element '{}': expected {used}, found {}",
            el.name,
            used + rest
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::scene::ply::fixtures::*;

    #[test]
    fn ascii_count_mismatch() {
        let ok =
            String::from_utf8(write_ply("ascii", &cube_elements("float", "uchar", "int"))).unwrap();
        // Header promises 9 vertices: the 9th "vertex" is the first edge line, short of values.
        let more = ok.replacen("element vertex 8", "element vertex 9", 1);
        assert_err(
            more.as_bytes(),
            "vertex 8 (line 35)",
            "too few values for element 'vertex': expected 7, found 2",
        );
        // 7 vertices: the 8th vertex line is read as the first edge and has too many values.
        let fewer = ok.replacen("element vertex 8", "element vertex 7", 1);
        assert_err(
            fewer.as_bytes(),
            "edge 0 (line 34)",
            "too many values for element 'edge': expected 2, found 7",
        );
        // 7 faces but only 6 lines.
        let faces = ok.replacen("element face 6", "element face 7", 1);
        assert_err(faces.as_bytes(), "face 6", "file ends after 6 of 7 faces");
    }
}
