//! The out-of-core prepare's temporary files: fixed-size little-endian records written and read
//! in order, in chunks. Triangles spilled in input order are 36-byte `[[f32; 3]; 3]` (their
//! primitive id is their index); a part's are `Record`s, the triangle and its primitive id.

use crate::error::{Error, Result};
use bytemuck::{Pod, Zeroable};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

pub type Triangle = [[f32; 3]; 3];

/// A triangle and its primitive id, 40 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Record {
    pub tri: Triangle,
    pub id: u32,
}

/// Records read at a time.
const CHUNK: usize = 1 << 15;

/// Appends records of type `T` to a new file.
pub struct Writer<T> {
    path: PathBuf,
    w: BufWriter<File>,
    pub count: u64,
    _t: std::marker::PhantomData<T>,
}

impl<T: Pod> Writer<T> {
    pub fn create(path: &Path, buffer: usize) -> Result<Writer<T>> {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        Ok(Writer {
            path: path.to_path_buf(),
            w: BufWriter::with_capacity(buffer, file),
            count: 0,
            _t: std::marker::PhantomData,
        })
    }

    pub fn push(&mut self, records: &[T]) -> Result<()> {
        self.count += records.len() as u64;
        self.w
            .write_all(bytemuck::cast_slice(records))
            .map_err(|e| Error::io(&self.path, e))
    }

    /// Flushes and closes the file: its path and record count.
    pub fn finish(self) -> Result<(PathBuf, u64)> {
        let Writer { path, w, count, .. } = self;
        w.into_inner()
            .map_err(|e| Error::io(&path, e.into_error()))?;
        Ok((path, count))
    }
}

/// Reads the `count` records of type `T` of a file, in chunks.
pub struct Reader<T> {
    path: PathBuf,
    file: File,
    left: u64,
    buf: Vec<T>,
}

impl<T: Pod> Reader<T> {
    pub fn open(path: &Path, count: u64) -> Result<Reader<T>> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let want = count * std::mem::size_of::<T>() as u64;
        if len != want {
            return Err(Error::Internal(format!(
                "{}: {len} bytes, {want} were written",
                path.display()
            )));
        }
        Ok(Reader {
            path: path.to_path_buf(),
            file,
            left: count,
            buf: Vec::new(),
        })
    }

    /// The next chunk of records, or `None` at the end.
    pub fn next_chunk(&mut self) -> Result<Option<&[T]>> {
        if self.left == 0 {
            return Ok(None);
        }
        let n = (self.left as usize).min(CHUNK);
        self.buf.resize(n, T::zeroed());
        self.file
            .read_exact(bytemuck::cast_slice_mut(&mut self.buf))
            .map_err(|e| Error::io(&self.path, e))?;
        self.left -= n as u64;
        Ok(Some(&self.buf))
    }

    /// Every remaining record.
    pub fn read_all(mut self) -> Result<Vec<T>> {
        let mut all = vec![T::zeroed(); self.left as usize];
        self.file
            .read_exact(bytemuck::cast_slice_mut(&mut all))
            .map_err(|e| Error::io(&self.path, e))?;
        Ok(all)
    }
}

/// Reads `count` records of type `T` from `file` at record `at`.
pub fn read_at<T: Pod>(file: &File, path: &Path, at: u64, count: usize) -> Result<Vec<T>> {
    use std::os::unix::fs::FileExt;
    let mut out = vec![T::zeroed(); count];
    file.read_exact_at(
        bytemuck::cast_slice_mut(&mut out),
        at * std::mem::size_of::<T>() as u64,
    )
    .map_err(|e| Error::io(path, e))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_in_chunks() {
        let dir = std::env::temp_dir().join(format!("dcrt-spill-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r");
        let mut w = Writer::<Record>::create(&path, 4096).unwrap();
        let all: Vec<Record> = (0..(CHUNK as u32 * 2 + 7))
            .map(|i| Record {
                tri: [[i as f32; 3]; 3],
                id: i,
            })
            .collect();
        for c in all.chunks(1000) {
            w.push(c).unwrap();
        }
        let (p, n) = w.finish().unwrap();
        assert_eq!(n, all.len() as u64);
        let mut r = Reader::<Record>::open(&p, n).unwrap();
        let mut back = Vec::new();
        while let Some(c) = r.next_chunk().unwrap() {
            back.extend_from_slice(c);
        }
        assert_eq!(back, all);
        assert_eq!(
            Reader::<Record>::open(&p, n).unwrap().read_all().unwrap(),
            all
        );
        let f = File::open(&p).unwrap();
        assert_eq!(read_at::<Record>(&f, &p, 5, 2).unwrap(), all[5..7]);
        assert!(Reader::<Record>::open(&p, n + 1).is_err());
        std::fs::remove_dir_all(dir).unwrap();
    }
}
