//! Loads a trace directory: every `frame_NNNN.rankR.jsonl`, each line checked against the record
//! schema (docs/ARCHITECTURE.md, Trace records). A bad line is an error naming the file and the
//! line; files of different runs in one directory are an error, never a partial result.

use super::record::{Display, FrameRecord, Grant, Render, Round, Tile, VERSION};
use crate::error::{Error, Result};
use serde::de::DeserializeOwned;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// One file: one frame at one rank.
#[derive(Clone, Debug, PartialEq)]
pub struct RankFrame {
    pub path: PathBuf,
    pub rounds: Vec<Round>,
    pub tiles: Vec<Tile>,
    pub grants: Vec<Grant>,
    pub displays: Vec<Display>,
    /// The display's `render` records: each render rank's report of the frame.
    pub renders: Vec<Render>,
    pub frame: FrameRecord,
}

impl RankFrame {
    pub fn faults(&self) -> u64 {
        self.rounds.iter().map(|r| r.faults.len() as u64).sum()
    }
}

/// Every file of a directory, ordered by frame then rank.
#[derive(Clone, Debug, PartialEq)]
pub struct Traces {
    pub dir: PathBuf,
    pub files: Vec<RankFrame>,
}

impl Traces {
    pub fn read(dir: &Path) -> Result<Traces> {
        let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
        let mut named = Vec::new();
        for e in entries {
            let path = e.map_err(|e| Error::io(dir, e))?.path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if !name.ends_with(".jsonl") {
                continue;
            }
            let Some(key) = parse_name(name) else {
                return Err(Error::format(
                    &path,
                    None,
                    "not a trace file name (frame_NNNN.rankR.jsonl)",
                ));
            };
            named.push((key, path));
        }
        if named.is_empty() {
            return Err(Error::format(
                dir,
                None,
                "no trace files (frame_NNNN.rankR.jsonl) in this directory",
            ));
        }
        named.sort();
        let mut files = Vec::with_capacity(named.len());
        for ((frame, rank), path) in named {
            let f = read_file(&path)?;
            if (f.frame.frame, f.frame.rank) != (frame, rank) {
                return Err(Error::format(
                    &path,
                    Some(format!("line {}", line_count(&f))),
                    format!(
                        "the frame record is frame {} rank {}, the file name says frame {frame} rank {rank}",
                        f.frame.frame, f.frame.rank
                    ),
                ));
            }
            files.push(f);
        }
        check_one_run(&files)?;
        Ok(Traces {
            dir: dir.to_path_buf(),
            files,
        })
    }

    /// The frame numbers, ascending.
    pub fn frames(&self) -> Vec<u32> {
        let mut f: Vec<u32> = self.files.iter().map(|f| f.frame.frame).collect();
        f.dedup();
        f
    }

    /// The ranks, ascending.
    pub fn ranks(&self) -> Vec<u32> {
        let mut r: Vec<u32> = self.files.iter().map(|f| f.frame.rank).collect();
        r.sort_unstable();
        r.dedup();
        r
    }

    pub fn get(&self, frame: u32, rank: u32) -> Option<&RankFrame> {
        self.files
            .iter()
            .find(|f| f.frame.frame == frame && f.frame.rank == rank)
    }
}

fn line_count(f: &RankFrame) -> usize {
    f.rounds.len() + f.tiles.len() + f.grants.len() + f.displays.len() + f.renders.len() + 1
}

fn parse_name(name: &str) -> Option<(u32, u32)> {
    let rest = name.strip_prefix("frame_")?.strip_suffix(".jsonl")?;
    let (frame, rank) = rest.split_once(".rank")?;
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !digits(frame) || !digits(rank) {
        return None;
    }
    Some((frame.parse().ok()?, rank.parse().ok()?))
}

fn read_file(path: &Path) -> Result<RankFrame> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let at = |n: usize, message: String| Error::format(path, Some(format!("line {n}")), message);
    let mut out = RankFrame {
        path: path.to_path_buf(),
        rounds: Vec::new(),
        tiles: Vec::new(),
        grants: Vec::new(),
        displays: Vec::new(),
        renders: Vec::new(),
        frame: FrameRecord::default(),
    };
    let mut frame = None;
    let mut last = 0;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        last = n;
        if frame.is_some() {
            return Err(at(
                n,
                "a record after the frame record (it must be last)".into(),
            ));
        }
        let v: Value = serde_json::from_str(line)
            .map_err(|e| at(n, format!("not a JSON object ({e}): truncated?")))?;
        let Some(kind) = v.get("type").and_then(Value::as_str).map(str::to_owned) else {
            return Err(at(n, "not a trace record (no \"type\")".into()));
        };
        match kind.as_str() {
            "round" => out.rounds.push(record(v, n, &at)?),
            "frame" => {
                let f: FrameRecord = record(v, n, &at)?;
                if f.version > VERSION {
                    return Err(at(
                        n,
                        format!(
                            "schema version {} is newer than this dcrt reads ({VERSION})",
                            f.version
                        ),
                    ));
                }
                frame = Some(f);
            }
            "tile" => out.tiles.push(record(v, n, &at)?),
            "grant" => out.grants.push(record(v, n, &at)?),
            "display" => out.displays.push(record(v, n, &at)?),
            "render" => out.renders.push(record(v, n, &at)?),
            t => return Err(at(n, format!("unknown record type \"{t}\""))),
        }
    }
    match frame {
        Some(f) => out.frame = f,
        None if last == 0 => return Err(Error::format(path, None, "empty trace file")),
        None => {
            return Err(at(
                last,
                "the file ends without its frame record: truncated?".into(),
            ));
        }
    }
    if out.rounds.len() != out.frame.fault_rounds as usize {
        return Err(at(
            last,
            format!(
                "the frame record counts {} fault rounds, the file holds {}",
                out.frame.fault_rounds,
                out.rounds.len()
            ),
        ));
    }
    Ok(out)
}

fn record<T: DeserializeOwned>(
    v: Value,
    n: usize,
    at: &impl Fn(usize, String) -> Error,
) -> Result<T> {
    let kind = v["type"].as_str().unwrap_or("").to_owned();
    serde_json::from_value(v).map_err(|e| at(n, format!("bad {kind} record: {e}")))
}

/// All files must name the same run (or, before version 1, at least the same world size).
fn check_one_run(files: &[RankFrame]) -> Result<()> {
    let first = &files[0];
    let line = |f: &RankFrame| Some(format!("line {}", line_count(f)));
    for f in &files[1..] {
        let (a, b) = (&first.frame, &f.frame);
        let why = if a.run != b.run {
            Some(format!(
                "run {} here, run {} in {}",
                b.run.as_deref().unwrap_or("(none)"),
                a.run.as_deref().unwrap_or("(none)"),
                first.path.display()
            ))
        } else if a.ranks != b.ranks {
            Some(format!(
                "{} ranks here, {} in {}",
                b.ranks,
                a.ranks,
                first.path.display()
            ))
        } else {
            None
        };
        if let Some(why) = why {
            return Err(Error::format(
                &f.path,
                line(f),
                format!("traces of different runs in one directory: {why}"),
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_name;

    #[test]
    fn names() {
        assert_eq!(parse_name("frame_0003.rank12.jsonl"), Some((3, 12)));
        assert_eq!(parse_name("frame_x.rank1.jsonl"), None);
        assert_eq!(parse_name("frame_0001.rank.jsonl"), None);
        assert_eq!(parse_name("stats.jsonl"), None);
    }
}
