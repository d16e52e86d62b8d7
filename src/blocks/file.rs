//! The block file (`.dcb`): the blocked model written once by `dcrt prepare`, from which each rank
//! reads only the blocks it owns.
//!
//! Layout (little endian):
//!
//! | offset | bytes | field |
//! |--------|-------|-------|
//! | 0 | 8 | magic `DCRTBLK\0` |
//! | 8 | 4 | version (1) |
//! | 12 | 4 | block size in bytes |
//! | 16 | 4 | node blocks |
//! | 20 | 4 | triangle blocks |
//! | 24 | 4 | root block (0: the root treelet's block) |
//! | 28 | 4 | metadata length M |
//! | 32 | 8 | offset of the first block (a multiple of 4096) |
//! | 40 | M | metadata: JSON (`Meta`: camera, image, meshes, bounds, BVH depth) |
//! | 40+M | 4 per block | CRC-32 of each block |
//! | data | block size per block | the blocks in id order |

use super::{Blocks, Format};
use crate::error::{Error, Result};
use crate::scene::Camera;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

pub const MAGIC: &[u8; 8] = b"DCRTBLK\0";
pub const VERSION: u32 = 1;
const FIXED: usize = 40;
const ALIGN: u64 = 4096;

/// What a renderer needs besides the blocks: the view and image it was prepared with, the
/// meshes' colours and primitive ranges, and the traversal stack depth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    pub camera: Camera,
    pub width: u32,
    pub height: u32,
    pub background: [f32; 3],
    pub mesh_first: Vec<u32>,
    pub colors: Vec<[f32; 3]>,
    pub triangles: u64,
    pub nodes: u64,
    pub bvh_depth: u32,
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
    /// The scene file it was prepared from, for people.
    pub source: String,
}

pub fn write(path: &Path, blocks: &Blocks, meta: &Meta) -> Result<()> {
    let io = |e| Error::io(path, e);
    let json = serde_json::to_vec(meta).map_err(|e| Error::Invalid(e.to_string()))?;
    let n = blocks.count() as u64;
    let table_end = FIXED as u64 + json.len() as u64 + 4 * n;
    let data = table_end.div_ceil(ALIGN) * ALIGN;
    let mut w = BufWriter::new(File::create(path).map_err(io)?);
    let mut head = Vec::with_capacity(FIXED);
    head.extend_from_slice(MAGIC);
    for v in [
        VERSION,
        blocks.format.block_bytes,
        blocks.node_blocks,
        blocks.tri_blocks,
        0,
        json.len() as u32,
    ] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    head.extend_from_slice(&data.to_le_bytes());
    w.write_all(&head).map_err(io)?;
    w.write_all(&json).map_err(io)?;
    for k in 0..blocks.count() {
        let crc = crc32fast::hash(bytemuck::cast_slice(blocks.block(k)));
        w.write_all(&crc.to_le_bytes()).map_err(io)?;
    }
    w.write_all(&vec![0u8; (data - table_end) as usize])
        .map_err(io)?;
    w.write_all(bytemuck::cast_slice(&blocks.words))
        .map_err(io)?;
    w.flush().map_err(io)
}

/// An open block file whose header, metadata and checksum table have been checked.
pub struct DcbFile {
    pub path: PathBuf,
    pub format: Format,
    pub node_blocks: u32,
    pub tri_blocks: u32,
    pub meta: Meta,
    checksums: Vec<u32>,
    data: u64,
    file: File,
}

impl DcbFile {
    pub fn open(path: &Path) -> Result<DcbFile> {
        let bad = |m: String| Error::format(path, None, m);
        let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let mut head = [0u8; FIXED];
        file.read_exact(&mut head).map_err(|_| {
            bad(format!(
                "truncated: {len} bytes, shorter than the {FIXED}-byte header"
            ))
        })?;
        if &head[..8] != MAGIC {
            return Err(bad("not a dcrt block file (bad magic)".into()));
        }
        let u = |i: usize| u32::from_le_bytes(head[i..i + 4].try_into().unwrap_or_default());
        let version = u(8);
        if version > VERSION {
            return Err(bad(format!(
                "format version {version} is newer than this dcrt reads ({VERSION}); \
                 prepare it again or update dcrt"
            )));
        }
        if version == 0 {
            return Err(bad("format version 0 is not valid".into()));
        }
        let format = Format::new(u(12)).map_err(|e| bad(e.to_string()))?;
        let (node_blocks, tri_blocks, root, meta_len) = (u(16), u(20), u(24), u(28) as u64);
        if root != 0 {
            return Err(bad(format!("root block {root}: only 0 is supported")));
        }
        let data = u64::from_le_bytes(head[32..40].try_into().unwrap_or_default());
        let n = u64::from(node_blocks) + u64::from(tri_blocks);
        let need = data + n * u64::from(format.block_bytes);
        if data < FIXED as u64 + meta_len + 4 * n || need > len || n == 0 {
            return Err(bad(format!(
                "truncated or inconsistent: the header describes {n} blocks of {} bytes \
                 ({need} bytes in all), the file has {len}",
                format.block_bytes
            )));
        }
        if need < len {
            return Err(bad(format!(
                "{} bytes after the last block: not the file that was prepared",
                len - need
            )));
        }
        let mut json = vec![0u8; meta_len as usize];
        file.read_exact(&mut json).map_err(|e| Error::io(path, e))?;
        let meta: Meta = serde_json::from_slice(&json)
            .map_err(|e| bad(format!("metadata is not valid: {e}")))?;
        let mut table = vec![0u8; 4 * n as usize];
        file.read_exact(&mut table)
            .map_err(|e| Error::io(path, e))?;
        let checksums = table
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        Ok(DcbFile {
            path: path.to_path_buf(),
            format,
            node_blocks,
            tri_blocks,
            meta,
            checksums,
            data,
            file,
        })
    }

    pub fn count(&self) -> u32 {
        self.node_blocks + self.tri_blocks
    }

    /// CRC-32 of the checksum table (see `Blocks::fingerprint`).
    pub fn fingerprint(&self) -> u32 {
        let mut h = crc32fast::Hasher::new();
        for c in &self.checksums {
            h.update(&c.to_le_bytes());
        }
        h.finalize()
    }

    /// Reads block `k` into `out` and checks it; `owner` names the rank it belongs to in errors.
    pub fn read_block_into(&self, k: u32, owner: u32, out: &mut [u32]) -> Result<()> {
        let bytes = u64::from(self.format.block_bytes);
        let buf: &mut [u8] = bytemuck::cast_slice_mut(out);
        self.file
            .read_exact_at(buf, self.data + u64::from(k) * bytes)
            .map_err(|e| Error::io(&self.path, e))?;
        if crc32fast::hash(buf) != self.checksums[k as usize] {
            return Err(Error::format(
                &self.path,
                Some(format!("block {k} (owner rank {owner})")),
                "checksum mismatch: the block is corrupt and is not rendered",
            ));
        }
        Ok(())
    }

    /// Every block, checked (a single-process render); `ranks` names owners in errors.
    pub fn read_all(&self, ranks: u32) -> Result<Blocks> {
        let bw = self.format.words() as usize;
        let mut words = vec![0u32; self.count() as usize * bw];
        for (k, chunk) in words.chunks_mut(bw).enumerate() {
            self.read_block_into(k as u32, k as u32 % ranks.max(1), chunk)?;
        }
        Ok(Blocks {
            format: self.format,
            node_blocks: self.node_blocks,
            tri_blocks: self.tri_blocks,
            words,
        })
    }
}

impl DcbFile {
    /// What one rank keeps on its GPU without the cache, and the only blocks it reads: its own
    /// blocks by slot, then the root block unless it owns it.
    pub fn read_resident(&self, ranks: crate::dc::Ranks) -> Result<Vec<u32>> {
        let bw = self.format.words() as usize;
        let rows = ranks.resident_rows(self.count());
        let mut words = vec![0u32; rows as usize * bw];
        for (k, chunk) in ranks
            .resident_blocks(self.count())
            .zip(words.chunks_mut(bw))
        {
            self.read_block_into(k, ranks.owner(k), chunk)?;
        }
        Ok(words)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bvh::{Bvh, Preset};
    use crate::scene::Model;

    fn sample() -> (Blocks, Meta) {
        let tris: Vec<_> = (0..2000)
            .map(|i| {
                let x = i as f32 * 0.1;
                [[x, 0.0, 0.0], [x + 0.05, 1.0, 0.0], [x, 0.0, 1.0]]
            })
            .collect();
        let model = Model::from_triangles(tris);
        let bvh = Bvh::build(&model, Preset::Fast, 256);
        let blocks = Blocks::pack(&bvh, Format::default()).unwrap();
        let meta = Meta {
            camera: crate::scene::fitted_camera(model.bounds),
            width: 64,
            height: 48,
            background: [0.0; 3],
            mesh_first: vec![0],
            colors: vec![[1.0; 3]],
            triangles: 2000,
            nodes: bvh.nodes.len() as u64,
            bvh_depth: bvh.depth,
            bounds_min: model.bounds.min,
            bounds_max: model.bounds.max,
            source: "test".into(),
        };
        (blocks, meta)
    }

    fn tmp(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("dcrt-dcb-{}-{name}", std::process::id()))
    }

    #[test]
    fn round_trip() {
        let (blocks, meta) = sample();
        let p = tmp("ok.dcb");
        write(&p, &blocks, &meta).unwrap();
        let f = DcbFile::open(&p).unwrap();
        assert_eq!(f.meta, meta);
        assert_eq!(f.read_all(1).unwrap().words, blocks.words);
        // A rank reads its own blocks and the root, nothing else.
        let r = crate::dc::Ranks::new(3, 2).unwrap();
        let words = f.read_resident(r).unwrap();
        let bw = blocks.format.words() as usize;
        let own: Vec<u32> = (0..blocks.count()).filter(|k| k % 3 == 2).collect();
        assert_eq!(words.len(), (own.len() + 1) * bw);
        for (s, &k) in own.iter().enumerate() {
            assert_eq!(&words[s * bw..(s + 1) * bw], blocks.block(k));
        }
        assert_eq!(&words[own.len() * bw..], blocks.block(0));
        std::fs::remove_file(p).unwrap();
    }

    #[test]
    fn damaged_files_are_refused() {
        let (blocks, meta) = sample();
        let p = tmp("bad.dcb");
        write(&p, &blocks, &meta).unwrap();
        let good = std::fs::read(&p).unwrap();
        let check = |bytes: &[u8], want: &str| {
            std::fs::write(&p, bytes).unwrap();
            let e = DcbFile::open(&p).and_then(|f| f.read_all(1).map(|_| ()));
            let e = e.expect_err(want).to_string();
            assert!(e.contains(want) && e.contains("bad.dcb"), "{e}");
        };
        check(&good[..good.len() - 100], "truncated");
        check(&good[..20], "truncated");
        let mut b = good.clone();
        b[0] = b'X';
        check(&b, "bad magic");
        let mut b = good.clone();
        b[8] = 2;
        check(&b, "newer");
        let mut b = good.clone();
        let last = b.len() - 5;
        b[last] ^= 1;
        let k = blocks.count() - 1;
        check(&b, &format!("block {k} (owner rank 0)"));
        let mut b = good.clone();
        b.push(0);
        check(&b, "after the last block");
        std::fs::remove_file(p).unwrap();
    }
}
