//! The block file (`.dcb`): the blocked model written once by `dcrt prepare`, from which each rank
//! reads only the blocks it owns.
//!
//! Layout (little endian):
//!
//! | offset | bytes | field |
//! |--------|-------|-------|
//! | 0 | 8 | magic `DCRTBLK\0` |
//! | 8 | 4 | version (4) |
//! | 12 | 4 | block size in bytes |
//! | 16 | 4 | node blocks |
//! | 20 | 4 | triangle blocks |
//! | 24 | 4 | root block (0: the root treelet's block) |
//! | 28 | 4 | metadata length M |
//! | 32 | 8 | offset of the first block (a multiple of 4096) |
//! | 40 | 4 | CRC-32 of bytes 0..40 and the metadata |
//! | 44 | M | metadata: JSON (`Meta`: camera, image, meshes and their looks, bounds, BVH depth, attribute layout) |
//! | 44+M | 4 per block | CRC-32 of each block |
//! | data | block size per block | the blocks in id order (nodes, triangles, then attributes) |
//!
//! Version 1 had no header checksum: a flipped bit in the metadata rendered another view.
//! Version 2 held binary 32-byte nodes; version 3 holds 4-wide quantized ones (`bvh::Node`);
//! version 4 adds the meshes' looks and the attribute blocks of models coloured by data (their
//! count is in the metadata).
//! Older versions are refused with a request to prepare the file again. On load the metadata is checked against the
//! header (counts, bounds, mesh table) and every block read is checked for structure (child and
//! leaf ranges, see `check`), so an edited block whose CRC was recomputed is refused too.

use super::{Blocks, Format};
use crate::error::{Error, Result};
use crate::scene::Camera;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

pub const MAGIC: &[u8; 8] = b"DCRTBLK\0";
pub const VERSION: u32 = 4;
const FIXED: usize = 44;
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
    /// How each mesh-table entry is coloured (empty: all by their colour).
    #[serde(default)]
    pub looks: Vec<crate::scene::color::Look>,
    /// The attribute blocks after the triangle blocks.
    #[serde(default)]
    pub attrs: super::AttrLayout,
}

/// Writes the block file through `files::write_atomic`: a failed write leaves no half file.
pub fn write(path: &Path, blocks: &Blocks, meta: &Meta) -> Result<()> {
    crate::files::write_atomic(path, |w| {
        let mut out = BlockWriter::start(
            w,
            path,
            blocks.format,
            blocks.node_blocks,
            blocks.tri_blocks,
            meta,
        )?;
        for k in 0..blocks.count() {
            out.block(blocks.block(k))?;
        }
        out.finish()
    })
}

/// Writes a block file a block at a time, in id order, for models whose blocks are never all in
/// memory (the out-of-core prepare): the header and metadata first, then the blocks, and last
/// the checksum table, which lies before the blocks and is written in place. `write` goes
/// through it too, so both make the same bytes.
pub struct BlockWriter<'w> {
    w: &'w mut BufWriter<File>,
    path: PathBuf,
    format: Format,
    count: u64,
    crcs: Vec<u32>,
    table_at: u64,
}

impl<'w> BlockWriter<'w> {
    /// Writes the header and metadata of a file of `node_blocks` + `tri_blocks` blocks (and the
    /// attribute blocks `meta.attrs` declares) into `w`
    /// (a file written by `files::write_atomic` for `path`, which errors name).
    pub fn start(
        w: &'w mut BufWriter<File>,
        path: &Path,
        format: Format,
        node_blocks: u32,
        tri_blocks: u32,
        meta: &Meta,
    ) -> Result<BlockWriter<'w>> {
        let io = |e| Error::io(path, e);
        let json = serde_json::to_vec(meta).map_err(|e| Error::Invalid(e.to_string()))?;
        // The attribute blocks (colours by data) follow the triangle blocks; their count is in
        // the metadata, as `DcbFile::open` reads it.
        let n = u64::from(node_blocks) + u64::from(tri_blocks) + u64::from(meta.attrs.blocks);
        if n > u64::from(u32::MAX) {
            return Err(Error::Invalid(format!(
                "model needs {n} blocks, more than 2^32"
            )));
        }
        let table_at = FIXED as u64 + json.len() as u64;
        let table_end = table_at + 4 * n;
        let data = table_end.div_ceil(ALIGN) * ALIGN;
        let mut head = Vec::with_capacity(FIXED);
        head.extend_from_slice(MAGIC);
        for v in [
            VERSION,
            format.block_bytes,
            node_blocks,
            tri_blocks,
            0,
            json.len() as u32,
        ] {
            head.extend_from_slice(&v.to_le_bytes());
        }
        head.extend_from_slice(&data.to_le_bytes());
        head.extend_from_slice(&header_crc(&head, &json).to_le_bytes());
        w.write_all(&head).map_err(io)?;
        w.write_all(&json).map_err(io)?;
        // The checksum table's place, filled by `finish`, and the padding to the first block.
        w.write_all(&vec![0u8; (data - table_at) as usize])
            .map_err(io)?;
        Ok(BlockWriter {
            w,
            path: path.to_path_buf(),
            format,
            count: n,
            crcs: Vec::with_capacity(n as usize),
            table_at,
        })
    }

    /// Appends the next block (`format.words()` words).
    pub fn block(&mut self, words: &[u32]) -> Result<()> {
        debug_assert_eq!(words.len(), self.format.words() as usize);
        if self.crcs.len() as u64 == self.count {
            return Err(Error::Internal(format!(
                "{}: more blocks than the {} the header declares",
                self.path.display(),
                self.count
            )));
        }
        let bytes: &[u8] = bytemuck::cast_slice(words);
        self.crcs.push(crc32fast::hash(bytes));
        self.w
            .write_all(bytes)
            .map_err(|e| Error::io(&self.path, e))
    }

    /// Checks that every declared block was written and fills in the checksum table.
    pub fn finish(self) -> Result<()> {
        let io = |e| Error::io(&self.path, e);
        if self.crcs.len() as u64 != self.count {
            return Err(Error::Internal(format!(
                "{}: {} blocks written, the header declares {}",
                self.path.display(),
                self.crcs.len(),
                self.count
            )));
        }
        self.w.flush().map_err(io)?;
        let table: Vec<u8> = self.crcs.iter().flat_map(|c| c.to_le_bytes()).collect();
        self.w
            .get_ref()
            .write_all_at(&table, self.table_at)
            .map_err(io)
    }
}

/// CRC-32 of the fixed header before the checksum field, then the metadata.
fn header_crc(head: &[u8], json: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&head[..FIXED - 4]);
    h.update(json);
    h.finalize()
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
        crate::scene::check_regular(path, "block file")?;
        let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let mut first = Vec::with_capacity(FIXED);
        (&mut file)
            .take(FIXED as u64)
            .read_to_end(&mut first)
            .map_err(|e| Error::io(path, e))?;
        let got = first.len();
        let mut head = [0u8; FIXED];
        head[..got].copy_from_slice(&first);
        if head[..got.min(8)] != MAGIC[..got.min(8)] || got == 0 {
            let text = head[..got]
                .iter()
                .all(|b| b.is_ascii_graphic() || b.is_ascii_whitespace());
            return Err(bad(if text && got > 0 {
                "not a dcrt block file (bad magic): it is text (a scene?); a block file is \
                 written by `dcrt prepare`"
                    .into()
            } else {
                "not a dcrt block file (bad magic)".into()
            }));
        }
        if got < FIXED {
            return Err(bad(format!(
                "truncated: {len} bytes, shorter than the {FIXED}-byte header"
            )));
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
        if version < VERSION {
            let why = match version {
                1 => "has no header checksum",
                2 => "holds binary BVH nodes",
                _ => "predates colour attributes",
            };
            return Err(bad(format!(
                "format version {version} {why} (this dcrt reads {VERSION}); \
                 prepare it again with `dcrt prepare`"
            )));
        }
        let format = Format::new(u(12)).map_err(|e| bad(e.to_string()))?;
        let (node_blocks, tri_blocks, root, meta_len) = (u(16), u(20), u(24), u(28) as u64);
        if root != 0 {
            return Err(bad(format!("root block {root}: only 0 is supported")));
        }
        let data = u64::from_le_bytes(head[32..40].try_into().unwrap_or_default());
        if FIXED as u64 + meta_len > len {
            return Err(bad(format!(
                "truncated: {len} bytes, shorter than the header and its {meta_len} bytes of \
                 metadata"
            )));
        }
        let mut json = vec![0u8; meta_len as usize];
        file.read_exact(&mut json).map_err(|e| Error::io(path, e))?;
        let stored = u32::from_le_bytes(head[40..44].try_into().unwrap_or_default());
        if header_crc(&head, &json) != stored {
            return Err(bad(
                "header or metadata checksum mismatch: the file is corrupt".into(),
            ));
        }
        let meta: Meta = serde_json::from_slice(&json)
            .map_err(|e| bad(format!("metadata is not valid: {e}")))?;
        super::check::meta(&meta, format, node_blocks, tri_blocks)
            .map_err(|m| bad(format!("metadata: {m}")))?;
        // The attribute blocks' count is in the (checked) metadata.
        let n = u64::from(node_blocks) + u64::from(tri_blocks) + u64::from(meta.attrs.blocks);
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
        self.node_blocks + self.tri_blocks + self.meta.attrs.blocks
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
        super::check::block(k, out, self.format, self.node_blocks, &self.meta).map_err(|m| {
            Error::format(
                &self.path,
                Some(format!("block {k} (owner rank {owner})")),
                format!("malformed: {m}"),
            )
        })
    }

    /// Every block, checked (a single-process render); `ranks` names owners in errors.
    pub fn read_all(&self, ranks: u32) -> Result<Blocks> {
        let bw = self.format.words() as usize;
        let mut words = vec![0u32; self.count() as usize * bw];
        for (k, chunk) in words.chunks_mut(bw).enumerate() {
            self.read_block_into(k as u32, k as u32 % ranks.max(1), chunk)?;
        }
        let blocks = Blocks {
            format: self.format,
            node_blocks: self.node_blocks,
            tri_blocks: self.tri_blocks,
            attrs: self.meta.attrs,
            words,
        };
        super::check::depth(&blocks, self.meta.bvh_depth)
            .map_err(|m| Error::format(&self.path, Some("node blocks".into()), m))?;
        Ok(blocks)
    }
}

impl DcbFile {
    /// What one rank keeps on its GPU without the cache, and the only blocks it reads: its own
    /// blocks by slot, then the replicated blocks it does not own.
    pub fn read_resident(&self, ranks: crate::blocks::ranks::Ranks) -> Result<Vec<u32>> {
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
    use crate::bvh::{Bvh, Child, Preset, WIDTH};
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
            looks: Vec::new(),
            attrs: Default::default(),
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
        let r = crate::blocks::ranks::Ranks::new(3, 2).unwrap();
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
        b[8] = 5;
        check(&b, "newer");
        let mut b = good.clone();
        b[8] = 1;
        check(&b, "version 1 has no header checksum");
        let mut b = good.clone();
        b[8] = 2;
        check(&b, "version 2 holds binary BVH nodes");
        let mut b = good.clone();
        b[8] = 3;
        check(&b, "version 3 predates colour attributes");
        // One flipped bit in the metadata: another camera, caught by the header checksum.
        let mut b = good.clone();
        let at = FIXED + find(&b[FIXED..], b"\"focal_point\":[").unwrap() + 15;
        b[at] ^= 4;
        check(&b, "metadata checksum mismatch");
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

    fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
        hay.windows(needle.len()).position(|w| w == needle)
    }

    /// Files whose checksums are all valid (as an edit that recomputes them gives) but whose
    /// metadata or blocks do not describe the prepared tree.
    #[test]
    fn consistent_checksums_do_not_hide_bad_contents() {
        let (blocks, meta) = sample();
        let p = tmp("edited.dcb");
        let check = |blocks: &Blocks, meta: &Meta, want: &str| {
            write(&p, blocks, meta).unwrap();
            let e = DcbFile::open(&p).and_then(|f| f.read_all(1).map(|_| ()));
            let e = e.expect_err(want).to_string();
            assert!(e.contains(want) && e.contains("edited.dcb"), "{e}");
        };
        let m = |f: &dyn Fn(&mut Meta)| {
            let mut m = meta.clone();
            f(&mut m);
            m
        };
        check(&blocks, &m(&|m| m.triangles = 1), "metadata: 1 triangles");
        check(&blocks, &m(&|m| m.nodes += 4096), "node blocks of 128");
        check(&blocks, &m(&|m| m.bounds_min[0] = 1e30), "not a finite box");
        check(&blocks, &m(&|m| m.mesh_first = vec![0, 5000]), "mesh table");
        check(&blocks, &m(&|m| m.bvh_depth += 1), "declares");
        check(
            &blocks,
            &m(&|m| m.bvh_depth -= 1),
            "deeper than the declared",
        );
        let edit = |f: &dyn Fn(&mut Blocks)| {
            let mut b = blocks.clone();
            f(&mut b);
            b
        };
        // All-zero blocks: the root's children would be the root itself.
        check(
            &edit(&|b| b.words.fill(0)),
            &meta,
            "block 0 (owner rank 0): malformed: node 0",
        );
        // A node the root reaches, zeroed: padding, which only unreached places may hold.
        check(
            &edit(&|b| b.words[16..32].fill(0)),
            &meta,
            "node 1 is padding",
        );
        // Word 4 is the root's `child_base`, 5 its `tri_base`.
        check(
            &edit(&|b| b.words[4] = 4_000_000),
            &meta,
            "node 0: children",
        );
        let leafy = (0..meta.nodes as u32)
            .find(|&i| (0..WIDTH).any(|s| matches!(blocks.node(i).child(s), Child::Leaf { .. })))
            .unwrap();
        let w = leafy as usize * 16 + 5;
        check(
            &edit(&|b| b.words[w] = 1 << 20),
            &meta,
            &format!("node {leafy}: leaf"),
        );
        // A lower bound above the upper one: a box no ray enters.
        check(
            &edit(&|b| {
                b.words[8] = 0xffff_ffff;
                b.words[11] = 0;
            }),
            &meta,
            "node 0: slot 0: bounds",
        );
        let id = (blocks.node_blocks * blocks.format.words() + blocks.format.id_word()) as usize;
        check(&edit(&|b| b.words[id] = 9999), &meta, "primitive id 9999");
        let v = (blocks.node_blocks * blocks.format.words()) as usize;
        check(
            &edit(&|b| b.words[v] = f32::NAN.to_bits()),
            &meta,
            "not finite",
        );
        std::fs::remove_file(p).unwrap();
    }
}
