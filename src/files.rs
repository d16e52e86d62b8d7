//! Files a run writes, safely (docs/ARCHITECTURE.md, Outputs): every output through a temporary
//! file renamed into place, checked before any work, and on failure or interruption the
//! unfinished ones removed and the finished frames kept; scratch directories for temporary
//! working files.

use crate::error::{Error as DcrtError, Result};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

/// Writes `path` through a temporary file beside it: `fill` writes the contents, then the file is
/// flushed, fsynced and renamed into place. On any error the temporary file is removed and what
/// was at `path` before stays. A `path` that exists but is not a regular file (a device, a FIFO,
/// a directory) is refused: renaming over it would replace the node itself. The file is one of
/// this run's outputs: `remove_written` and an interruption (`remove_on_interrupt`) remove it
/// unless it belongs to a finished frame (`keep_frame`).
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    write_file(path, true, fill)
}

/// Writes a record (a trace file) as `write_atomic` does, but without the fsync, and keeps it
/// when the run fails or is interrupted: what a run did up to then is worth reading. Readers see
/// the whole file or none of it.
pub fn write_record(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    write_file(path, false, fill)
}

/// What this process has written (`done`), finished as whole frames (`kept`), and is writing
/// (`partial`): an interrupted or failed run removes the partial and the done, and keeps the
/// kept (docs/ARCHITECTURE.md, Outputs). Held only to create, rename and remove, never while a
/// file is filled, so an interruption waits for no write.
struct Written {
    done: Vec<PathBuf>,
    partial: Vec<PathBuf>,
    /// Directories of temporary files (`Scratch`), removed with everything in them.
    scratch: Vec<PathBuf>,
    /// The outputs of finished frames, the number of those frames and the last of them.
    kept: Vec<PathBuf>,
    frames: u32,
    last_frame: Option<u32>,
}

static WRITTEN: Mutex<Written> = Mutex::new(Written {
    done: Vec::new(),
    partial: Vec::new(),
    scratch: Vec::new(),
    kept: Vec::new(),
    frames: 0,
    last_frame: None,
});

fn written() -> MutexGuard<'static, Written> {
    // A panic elsewhere while holding it leaves the lists as they were: still right.
    WRITTEN.lock().unwrap_or_else(|e| e.into_inner())
}

fn write_file(
    path: &Path,
    output: bool,
    fill: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    check_target(path)?;
    let tmp = partial_path(path);
    let io = |e| DcrtError::io(path, e);
    let file = {
        // Created while registered, so an interruption either sees it or precedes it.
        let mut w = written();
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| DcrtError::io(&tmp, e))?;
        w.partial.push(tmp.clone());
        file
    };
    let filled = (|| {
        let mut w = BufWriter::new(file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| io(e.into_error()))?;
        if output {
            file.sync_all().map_err(io)?;
        }
        Ok(())
    })();
    let mut w = written();
    w.partial.retain(|p| p != &tmp);
    let done = filled.and_then(|()| std::fs::rename(&tmp, path).map_err(io));
    match &done {
        Ok(()) if output => w.done.push(path.to_path_buf()),
        Ok(()) => {}
        Err(_) => {
            let _ = std::fs::remove_file(&tmp);
        }
    }
    done
}

/// Marks the outputs of finished frame `frame` (all of them written) as kept: a failed or
/// interrupted run leaves them, as a user who stops a long sequence expects the frames it
/// finished. Frames may finish out of order (the display writes them on threads of their own).
pub fn keep_frame(frame: u32, paths: &[&Path]) {
    let mut w = written();
    w.done.retain(|p| !paths.contains(&p.as_path()));
    w.kept.extend(paths.iter().map(|p| p.to_path_buf()));
    w.frames += 1;
    w.last_frame = w.last_frame.max(Some(frame));
}

/// Removes the outputs this process has written that are not kept frames (a failed run leaves
/// nothing half done), and says what it keeps: `kept 722 frames in k/`, or `None` when it keeps
/// nothing.
pub fn remove_written() -> Option<String> {
    let mut w = written();
    for p in w.done.drain(..) {
        let _ = std::fs::remove_file(p);
    }
    kept_summary(&w)
}

/// `after frame 721: kept 722 frames in k/`, or `None` when no frame was finished.
fn kept_summary(w: &Written) -> Option<String> {
    let last = w.last_frame?;
    let mut dirs: Vec<String> = Vec::new();
    for p in &w.kept {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => format!("{}/", d.display()),
            _ => "./".into(),
        };
        if !dirs.contains(&dir) {
            dirs.push(dir);
        }
    }
    let frames = if w.frames == 1 { "frame" } else { "frames" };
    Some(format!(
        "after frame {last}: kept {} {frames} in {}",
        w.frames,
        dirs.join(" and ")
    ))
}

/// Installs the answer to SIGTERM, SIGINT and SIGHUP for a command that writes outputs: a thread
/// that, on the first of them, removes the run's temporary files (`Scratch` directories too) and
/// the outputs of frames it had not finished, keeps the finished frames (`keep_frame`) and trace
/// records, says so on stderr (waiting at most `MESSAGE_WAIT` for a stderr nobody reads) and
/// exits with 128 + the signal's number, whatever the rest of the process is doing (a GPU wait,
/// an MPI call, a write to a full stderr). A file being renamed into place is waited
/// for, so none is left half done. A process that has written nothing waits `idle_grace` first:
/// an MPI launcher kills every rank as soon as one has exited, and the rank that writes the
/// frames needs the time to finish (docs/ARCHITECTURE.md, Outputs).
pub fn remove_on_interrupt(idle_grace: std::time::Duration) -> Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGTERM, SIGINT, SIGHUP])
        .map_err(|e| DcrtError::Internal(format!("cannot install the signal handlers: {e}")))?;
    std::thread::Builder::new()
        .name("dcrt-signals".into())
        .spawn(move || {
            if let Some(sig) = signals.forever().next() {
                // Held until the exit: no write starts or finishes after this.
                let w = written();
                for p in w.partial.iter().chain(&w.done) {
                    let _ = std::fs::remove_file(p);
                }
                for d in &w.scratch {
                    let _ = std::fs::remove_dir_all(d);
                }
                let name = match sig {
                    SIGTERM => "SIGTERM",
                    SIGINT => "SIGINT",
                    _ => "SIGHUP",
                };
                let removed = match w.done.len() {
                    0 => String::new(),
                    n => format!("; removed {n} unfinished output(s)"),
                };
                let message = match kept_summary(&w) {
                    Some(kept) => format!("error: interrupted by {name} {kept}{removed}"),
                    None if w.done.is_empty() => format!("error: interrupted by {name}"),
                    None => format!(
                        "error: interrupted by {name}; removed the {} output file(s) this run wrote",
                        w.done.len()
                    ),
                };
                say_at_most(message, MESSAGE_WAIT);
                if w.kept.is_empty()
                    && w.done.is_empty()
                    && w.partial.is_empty()
                    && w.scratch.is_empty()
                {
                    std::thread::sleep(idle_grace);
                }
                signal_hook::low_level::exit(128 + sig);
            }
        })
        .map_err(|e| DcrtError::Internal(format!("cannot start the signal thread: {e}")))?;
    Ok(())
}

/// How long an interruption waits for its message to reach stderr before it exits anyway.
const MESSAGE_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Writes `line` to stderr from a thread of its own and waits at most `wait` for it: a stderr
/// that nobody reads (a full pipe, a paused pager) blocks its writer, and holds stderr's lock
/// against every other one, and must not keep an interrupted process from ending.
fn say_at_most(line: String, wait: std::time::Duration) {
    let (tx, rx) = std::sync::mpsc::channel();
    let text = line.clone();
    let spawned = std::thread::Builder::new()
        .name("dcrt-signal-message".into())
        .spawn(move || {
            crate::progress::stderr_line(&text);
            let _ = tx.send(());
        });
    match spawned {
        Ok(_) => {
            let _ = rx.recv_timeout(wait);
        }
        // No thread to spare: the message is worth the risk of the wait.
        Err(_) => crate::progress::stderr_line(&line),
    }
}

/// Grows a stderr pipe to 1 MiB, or to the most the system allows an unprivileged process if
/// that is less, for a rank that writes a line a frame under mpirun: mpirun stops reading its
/// ranks' pipes while it stops a job (SIGCONT, a second's sleep, SIGTERM, another, SIGKILL), and
/// with the default 64 KiB such a rank filled its pipe in that second, blocked in the write and
/// was killed before its interruption message (`remove_on_interrupt`) said what it kept. 1 MiB
/// holds a second of lines at over 5,000 frames a second. Only for the ranks that need it: every
/// 1 MiB pipe counts against the user's pipe pages (64 MiB by default), past which the kernel
/// gives every new pipe of that user a single page. Not a pipe, or a larger one already: left
/// as it is.
pub fn enlarge_stderr_pipe() {
    use std::os::fd::AsFd;
    const WANT: usize = 1 << 20;
    let stderr = std::io::stderr();
    let Ok(have) = rustix::pipe::fcntl_getpipe_size(stderr.as_fd()) else {
        return;
    };
    let most = std::fs::read_to_string("/proc/sys/fs/pipe-max-size")
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(WANT);
    let want = WANT.min(most);
    if have >= want {
        return;
    }
    match rustix::pipe::fcntl_setpipe_size(stderr.as_fd(), want) {
        Ok(size) => log::debug!("stderr pipe grown from {have} to {size} bytes"),
        Err(e) => log::warn!(
            "stderr pipe left at {have} bytes ({e}): if mpirun stops the job while it is full, \
             the message saying which frames were kept may be lost"
        ),
    }
}

/// A directory of temporary files beside an output (the out-of-core prepare's spilled
/// triangles and parts): hidden, unique to the process, removed with its contents when dropped
/// (success or failure) and by an interruption (`remove_on_interrupt`).
pub struct Scratch {
    dir: PathBuf,
}

impl Scratch {
    /// A new directory beside `output`, in the same file system as the output will be.
    pub fn beside(output: &Path) -> Result<Scratch> {
        let name = output
            .file_name()
            .map(|n| n.to_string_lossy())
            .unwrap_or_default();
        let dir = output.with_file_name(format!(".{name}.{}.parts", std::process::id()));
        // Created while registered, so an interruption either sees it or precedes it.
        let mut w = written();
        std::fs::create_dir(&dir).map_err(|e| DcrtError::io(&dir, e))?;
        w.scratch.push(dir.clone());
        Ok(Scratch { dir })
    }

    /// The path of a temporary file `name` in the directory.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let mut w = written();
        let _ = std::fs::remove_dir_all(&self.dir);
        w.scratch.retain(|d| d != &self.dir);
    }
}

/// Writes `bytes` to `path` as `write_atomic` does.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |w| {
        w.write_all(bytes).map_err(|e| DcrtError::io(path, e))
    })
}

/// The temporary name `write_atomic` uses: hidden, in the target's directory (so the rename
/// stays on one filesystem), unique to this process.
fn partial_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.partial", std::process::id()))
}

/// Refuses an output path that exists but is not a regular file.
fn check_target(path: &Path) -> Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => Err(DcrtError::Invalid(format!(
            "{}: the output exists and is not a regular file ({}); dcrt replaces only regular files",
            path.display(),
            kind_of(&m)
        ))),
        _ => Ok(()),
    }
}

/// What a file system entry is, for messages.
pub fn kind_of(m: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = m.file_type();
    if t.is_dir() {
        "a directory"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_file() {
        "a regular file"
    } else {
        "not a regular file"
    }
}

/// Checks a run's outputs before any work. Each is `(what, path, frames)`: a kind for messages,
/// the path as given, and the frames it is written for (numbered as `numbered` does). Each one's
/// directory must exist and take a new file, none may exist as something other than a regular
/// file, no two may be the same path, and none may be one of the run's `inputs`. So a run never
/// fails after rendering because of a path, and never replaces what it reads.
pub fn check_outputs(outputs: &[(&str, &Path, u32)], inputs: &[PathBuf]) -> Result<()> {
    for (k, &(what, path, frames)) in outputs.iter().enumerate() {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        if !dir.is_dir() {
            return Err(DcrtError::Invalid(format!(
                "{}: the {what} directory {} does not exist",
                path.display(),
                dir.display()
            )));
        }
        for &(other, earlier, _) in &outputs[..k] {
            if same_file(path, earlier) {
                return Err(DcrtError::Invalid(format!(
                    "{}: given as both the {other} and the {what} output; they must differ",
                    path.display()
                )));
            }
        }
        for i in 0..frames {
            let p = numbered(path, i, frames);
            check_target(&p)?;
            if let Some(input) = inputs.iter().find(|input| same_file(&p, input)) {
                return Err(DcrtError::Invalid(format!(
                    "{}: the {what} output would replace the input {}",
                    p.display(),
                    input.display()
                )));
            }
        }
        // A probe file proves the directory takes new files (permissions, a read-only mount).
        let probe = partial_path(path);
        let _w = written();
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&probe)
            .map_err(|e| {
                DcrtError::Invalid(format!(
                    "{}: cannot create the {what} output in {}: {e}",
                    path.display(),
                    dir.display()
                ))
            })?;
        let _ = std::fs::remove_file(&probe);
    }
    Ok(())
}

/// Whether two paths name the same file: the same inode when both exist, else the same path
/// once the directory part is resolved.
pub fn same_file(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    if let (Ok(x), Ok(y)) = (std::fs::metadata(a), std::fs::metadata(b)) {
        return x.dev() == y.dev() && x.ino() == y.ino();
    }
    let resolve = |p: &Path| -> Option<PathBuf> {
        let dir = match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        Some(dir.canonicalize().ok()?.join(p.file_name()?))
    };
    match (resolve(a), resolve(b)) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

/// The output path of frame `i` of `frames`: `path` itself for a single frame, else numbered
/// (`out.png` → `out_0000.png`, ...).
pub fn numbered(path: &Path, i: u32, frames: u32) -> std::path::PathBuf {
    if frames == 1 {
        return path.to_path_buf();
    }
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("out");
    let ext = path.extension().and_then(|s| s.to_str()).unwrap_or("png");
    path.with_file_name(format!("{stem}_{i:04}.{ext}"))
}

/// Writes an image as PNG, atomically (`write_bytes`).
pub fn write_rgb_png(path: &Path, img: &image::RgbImage) -> Result<()> {
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| crate::error::Error::format(path, None, e.to_string()))?;
    write_bytes(path, &png)
}
