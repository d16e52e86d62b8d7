//! The binary PLY body (either byte order): records decoded in place from the reader's buffer,
//! piece by piece where a record straddles its end, and elements without kept properties
//! skipped whole.

use super::Builder;
use super::header::{Element, Header, Kind, Role, Scalar, Target};
use crate::error::{Error, Result};
use std::io::{self, BufRead, Read};
use std::path::Path;

/// Reads a fixed-size number from the front of a slice the caller has sized for it.
macro_rules! decode {
    ($t:ty, $b:expr, $big:expr) => {{
        let mut a = [0u8; size_of::<$t>()];
        a.copy_from_slice(&$b[..size_of::<$t>()]);
        if $big {
            <$t>::from_be_bytes(a)
        } else {
            <$t>::from_le_bytes(a)
        }
    }};
}

impl Scalar {
    /// Decodes a binary value from `b[..self.size()]`.
    #[inline]
    fn decode(self, b: &[u8], big: bool) -> f64 {
        match self {
            Self::I8 => f64::from(decode!(i8, b, big)),
            Self::U8 => f64::from(b[0]),
            Self::I16 => f64::from(decode!(i16, b, big)),
            Self::U16 => f64::from(decode!(u16, b, big)),
            Self::I32 => f64::from(decode!(i32, b, big)),
            Self::U32 => f64::from(decode!(u32, b, big)),
            Self::F32 => f64::from(decode!(f32, b, big)),
            Self::F64 => decode!(f64, b, big),
        }
    }
}

/// Why reading one binary record failed.
enum Fault {
    Io(io::Error),
    Bad(String),
}

impl From<io::Error> for Fault {
    fn from(e: io::Error) -> Self {
        Fault::Io(e)
    }
}

impl From<String> for Fault {
    fn from(msg: String) -> Self {
        Fault::Bad(msg)
    }
}

pub(super) fn read_binary<R: BufRead>(
    r: &mut R,
    header: &Header,
    big: bool,
    b: &mut Builder,
    origin: &Path,
) -> Result<()> {
    for el in &header.elements {
        let fail = |i: u64, fault: Fault| match fault {
            Fault::Io(e) if e.kind() == io::ErrorKind::UnexpectedEof => Error::format(
                origin,
                Some(format!("{} {i}", el.name)),
                format!("file ends after {i} of {} {}", el.count, el.plural()),
            ),
            Fault::Io(e) => Error::io(origin, e),
            Fault::Bad(msg) => Error::format(origin, Some(format!("{} {i}", el.name)), msg),
        };
        match el.fixed_size() {
            Some(0) => {}
            // Nothing to keep: skip the whole element in one copy.
            Some(size) if el.target == Target::Other => {
                let size = size as u64;
                let want = el.count.saturating_mul(size);
                let got = skip(r, want).map_err(|e| fail(0, e.into()))?;
                if got < want {
                    let eof = io::Error::from(io::ErrorKind::UnexpectedEof);
                    return Err(fail(got / size, eof.into()));
                }
            }
            _ => {
                let mut scratch = [0u8; 1024];
                let mut i = 0;
                while i < el.count {
                    // Decode the records lying wholly in the reader's buffer in place: no copy
                    // and no read call per record.
                    let data = r.fill_buf().map_err(|e| fail(i, e.into()))?;
                    let mut used = 0;
                    while i < el.count {
                        b.poly.clear();
                        let Some(len) = record_from_slice(&data[used..], el, big, b)
                            .map_err(|m| fail(i, m.into()))?
                        else {
                            break;
                        };
                        b.finish(el.target).map_err(|m| fail(i, m.into()))?;
                        used += len;
                        i += 1;
                    }
                    r.consume(used);
                    if used == 0 && i < el.count {
                        // The record straddles the buffer's end, is bigger than the buffer, or
                        // is cut short by the end of the file: read it piece by piece.
                        b.poly.clear();
                        binary_record(r, el, big, b, &mut scratch).map_err(|f| fail(i, f))?;
                        b.finish(el.target).map_err(|m| fail(i, m.into()))?;
                        i += 1;
                    }
                }
            }
        }
    }
    let extra = skip(r, u64::MAX).map_err(|e| Error::io(origin, e))?;
    if extra > 0 {
        return Err(Error::format(
            origin,
            None,
            format!("{extra} bytes of data after the last element"),
        ));
    }
    Ok(())
}

/// Decodes one binary record from the front of `data`, returning its length in bytes, or `None`
/// if `data` holds only part of it.
#[inline]
fn record_from_slice(
    data: &[u8],
    el: &Element,
    big: bool,
    b: &mut Builder,
) -> std::result::Result<Option<usize>, String> {
    let mut at = 0;
    for p in &el.props {
        match p.kind {
            Kind::Scalar(t) => {
                let Some(v) = data.get(at..at + t.size()) else {
                    return Ok(None);
                };
                b.scalar(p.role, t.decode(v, big));
                at += t.size();
            }
            Kind::List { count, item } => {
                let Some(c) = data.get(at..at + count.size()) else {
                    return Ok(None);
                };
                let n = count.decode(c, big);
                if n < 0.0 {
                    return Err(format!("list '{}' has negative length {n}", p.name));
                }
                at += count.size();
                let len = (n as usize).saturating_mul(item.size());
                let Some(items) = data.get(at..at.saturating_add(len)) else {
                    return Ok(None);
                };
                if p.role == Role::Indices {
                    for v in items.chunks_exact(item.size()) {
                        b.index(item.decode(v, big))?;
                    }
                }
                at += len;
            }
        }
    }
    Ok(Some(at))
}

/// Reads one binary record piece by piece, for records not wholly in the reader's buffer.
fn binary_record<R: BufRead>(
    r: &mut R,
    el: &Element,
    big: bool,
    b: &mut Builder,
    scratch: &mut [u8; 1024],
) -> std::result::Result<(), Fault> {
    for p in &el.props {
        match p.kind {
            Kind::Scalar(t) => {
                let bytes = &mut scratch[..t.size()];
                r.read_exact(bytes)?;
                b.scalar(p.role, t.decode(bytes, big));
            }
            Kind::List { count, item } => {
                let bytes = &mut scratch[..count.size()];
                r.read_exact(bytes)?;
                let n = count.decode(bytes, big);
                if n < 0.0 {
                    return Err(format!("list '{}' has negative length {n}", p.name).into());
                }
                let (n, size) = (n as u64, item.size());
                if p.role != Role::Indices {
                    let want = n.saturating_mul(size as u64);
                    if skip(r, want)? < want {
                        return Err(io::Error::from(io::ErrorKind::UnexpectedEof).into());
                    }
                    continue;
                }
                // Whole chunks at a time: one read for a typical face.
                let per_chunk = (scratch.len() / size) as u64;
                let mut left = n;
                while left > 0 {
                    let k = left.min(per_chunk);
                    let bytes = &mut scratch[..k as usize * size];
                    r.read_exact(bytes)?;
                    for v in bytes.chunks_exact(size) {
                        b.index(item.decode(v, big))?;
                    }
                    left -= k;
                }
            }
        }
    }
    Ok(())
}

/// Discards up to `n` bytes, returning how many there were.
fn skip<R: BufRead>(r: &mut R, n: u64) -> io::Result<u64> {
    io::copy(&mut r.by_ref().take(n), &mut io::sink())
}

#[cfg(test)]
mod tests {
    use crate::scene::ply::fixtures::*;
    use crate::scene::ply::parse_ply;
    use std::io;
    use std::path::Path;

    #[test]
    fn records_straddling_the_read_buffer() {
        // Tiny buffers force the piecewise path for records cut by the buffer's end.
        let want = expected_cube();
        for format in FORMATS {
            let file = write_ply(format, &cube_elements("double", "ushort", "uint"));
            for capacity in 1..48 {
                let reader = io::BufReader::with_capacity(capacity, &file[..]);
                assert_same(&parse_ply(reader, Path::new("t.ply")).unwrap(), &want);
                let cut = io::BufReader::with_capacity(capacity, &file[..file.len() - 6]);
                let err = parse_ply(cut, Path::new("t.ply")).unwrap_err().to_string();
                assert!(err.contains("face 5"), "{err}");
            }
        }
    }

    #[test]
    fn truncated_binary() {
        for format in &FORMATS[1..] {
            let file = write_ply(format, &cube_elements("float", "uchar", "int"));
            let header = file.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
            let material = (1 + 1 + 2 * 4 + 8) + (1 + 1 + 8);
            let vertex = 4 + 3 * 4 + 2 + 1 + 8;
            // Cut inside the 8th vertex (index 7).
            let cut = header + material + 7 * vertex + 5;
            assert_err(&file[..cut], "vertex 7", "file ends after 7 of 8 vertices");
            // Cut inside the skipped edge element and inside the last face.
            assert_err(
                &file[..cut + vertex + 9],
                "edge 1",
                "file ends after 1 of 2 edges",
            );
            assert_err(
                &file[..file.len() - 3],
                "face 5",
                "file ends after 5 of 6 faces",
            );
            assert_err(
                &file[..header],
                "material 0",
                "file ends after 0 of 2 materials",
            );
        }
    }
}
