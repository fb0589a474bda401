//! Crash and resource isolation: every job's untrusted frame is decoded
//! and searched in a worker process (`gcp-tagger run-job`, one per worker
//! thread, kept across jobs so libraries load once), so a segfault or abort
//! in GDAL or OpenCV, or a runaway, ends that process only; the next job
//! gets a fresh one.
//!
//! For each job (a [`ParentLine::Job`] on its stdin) the process reads the
//! frame's header, says how much memory it needs, and waits; the parent
//! takes that share of the RAM budget and answers [`ParentLine::Go`] with
//! the limits; the
//! process then caps itself for the job (soft RLIMIT_DATA at its current
//! data size plus the reservation and headroom, soft RLIMIT_CPU from the frame's
//! size), runs, and lifts the caps afterwards. It dies with the server (PR_SET_PDEATHSIG, set by the child:
//! spawning goes through posix_spawn, never a bare fork, see
//! [`JobChild::spawn`]). Protocol: one JSON message per line, a
//! [`ParentLine`] on the child's stdin, a [`ChildLine`] on its stdout, e.g.
//!
//! ```text
//! {"kind":"header","width":4000,"height":3000,"need":71303168}
//! {"kind":"go","data_limit":536870912,"cpu_secs":84}
//! {"kind":"tile","done":3,"total":12}
//! {"kind":"done","targets":8,"width":4000,"height":3000}   (result JSON in the order's file)
//! {"kind":"error","code":"unreadable_frame","message":"..."}
//! ```

use std::io::{BufRead, BufReader, Write};
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, ExitCode, Stdio};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::time::Duration;

use crate::pipeline::frame::{detect_frame_pictured, need_bytes, FrameError, FrameObserver};
use crate::pipeline::georef::Transformer;
use crate::pipeline::memory::MIB;
use crate::pipeline::pictures::Pictures;
use crate::pipeline::raster::{open_frame, RasterError};

use super::params::JobParams;
use crate::error_code::ErrorCode;

/// What the parent says to the child.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ParentLine {
    /// Run this job: read its header and answer [`ChildLine::Header`].
    Job(Box<JobOrder>),
    /// Go on with the job within these limits.
    Go { data_limit: u64, cpu_secs: u64 },
}

/// What the child said last.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ChildLine {
    Header {
        width: u32,
        height: u32,
        need: u64,
    },
    Tile {
        done: u32,
        total: u32,
    },
    Done {
        targets: u32,
        width: u32,
        height: u32,
    },
    Error {
        code: ErrorCode,
        message: String,
    },
    /// A condition the user should hear that did not stop the frame.
    Warning {
        message: String,
    },
}

impl ChildLine {
    /// A line the child wrote; None for anything else (a library's stray
    /// output on stdout).
    pub fn parse(line: &str) -> Option<ChildLine> {
        serde_json::from_str(line).ok()
    }
}

/// What a wait for the child's next line gave.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Heard {
    Line(String),
    /// Nothing within the timeout.
    Nothing,
    /// The child closed its output: it has ended.
    Ended,
}

/// A running child and its lines.
pub struct JobChild {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
}

/// CPU seconds a frame may take: a minute plus 2 s per megapixel, about
/// 30 times what the slowest mode needs on one core.
pub fn cpu_limit_secs(width: u32, height: u32) -> u64 {
    60 + 2 * (width as u64 * height as u64).div_ceil(1_000_000)
}

impl JobChild {
    /// Starts a worker process (`gcp-tagger run-job`); jobs go to it with
    /// [`JobChild::send`].
    pub fn spawn() -> std::io::Result<JobChild> {
        let exe = std::env::current_exe()?;
        let mut cmd = Command::new(exe);
        cmd.arg("run-job")
            .arg("--parent")
            .arg(std::process::id().to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        // No pre_exec hook: that would make std fork() instead of
        // posix_spawn(), and fork runs libproj's atfork handler, which
        // closes PROJ's SQLite database in the child and can deadlock on a
        // SQLite mutex another thread held at the fork. The child sets its
        // parent-death signal itself.
        let mut child = cmd.spawn()?;
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, lines) = mpsc::channel();
        std::thread::Builder::new()
            .name("job-child-reader".into())
            .spawn(move || {
                for line in BufReader::new(stdout).lines() {
                    let Ok(line) = line else { break };
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            })?;
        Ok(JobChild {
            child,
            stdin,
            lines,
        })
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// The next line, waiting at most `timeout`.
    pub fn next_line(&self, timeout: Duration) -> Heard {
        match self.lines.recv_timeout(timeout) {
            Ok(line) => Heard::Line(line),
            Err(RecvTimeoutError::Timeout) => Heard::Nothing,
            Err(RecvTimeoutError::Disconnected) => Heard::Ended,
        }
    }

    /// Sends a job; the child answers `header`, then waits for [`go`].
    ///
    /// [`go`]: JobChild::go
    pub fn send(&mut self, order: &JobOrder) -> std::io::Result<()> {
        let stdin = self.stdin.as_mut().ok_or(std::io::ErrorKind::BrokenPipe)?;
        write_line(stdin, &ParentLine::Job(Box::new(order.clone())))
    }

    /// Lets the child run with these limits.
    pub fn go(&mut self, data_limit: u64, cpu_secs: u64) -> std::io::Result<()> {
        let stdin = self.stdin.as_mut().ok_or(std::io::ErrorKind::BrokenPipe)?;
        write_line(
            stdin,
            &ParentLine::Go {
                data_limit,
                cpu_secs,
            },
        )
    }

    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Waits for the end and describes an abnormal one; `None` for exit 0.
    pub fn wait_abnormal(&mut self) -> Option<String> {
        self.stdin.take();
        match self.child.wait() {
            Ok(status) if status.success() => None,
            Ok(status) => Some(match status.signal() {
                Some(sig) => format!("killed by signal {sig} ({})", signal_name(sig)),
                None => format!("exited with status {}", status.code().unwrap_or(-1)),
            }),
            Err(e) => Some(format!("cannot be waited for: {e}")),
        }
    }
}

impl Drop for JobChild {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            self.kill();
        }
    }
}

pub fn signal_name(sig: i32) -> &'static str {
    match sig {
        libc::SIGSEGV => "SIGSEGV, a crash",
        libc::SIGABRT => "SIGABRT, an abort or out of its memory limit",
        libc::SIGBUS => "SIGBUS, a crash",
        libc::SIGFPE => "SIGFPE, a crash",
        libc::SIGILL => "SIGILL, a crash",
        libc::SIGKILL => "SIGKILL",
        libc::SIGXCPU => "SIGXCPU, over its CPU time limit",
        _ => "a signal",
    }
}

/// Stable codes for frames that cannot be read.
pub fn raster_code(e: &RasterError) -> ErrorCode {
    match e {
        RasterError::Unsupported(_) => ErrorCode::UnsupportedFrame,
        RasterError::TooSmall { .. } => ErrorCode::FrameTooSmall,
        RasterError::Bands(_) => ErrorCode::UnsupportedBands,
        RasterError::Empty => ErrorCode::EmptyFrame,
        RasterError::Io(_)
        | RasterError::RefusedPath(_)
        | RasterError::Decode { .. }
        | RasterError::CutOff { .. } => ErrorCode::UnreadableFrame,
    }
}

/// Arguments of the hidden `run-job` subcommand.
#[derive(clap::Args, Debug)]
pub struct RunJobArgs {
    /// The server's pid: the worker process dies with it.
    #[arg(long)]
    pub parent: Option<u32>,
}

/// One message as one line of JSON.
fn write_line(out: &mut impl Write, message: &impl serde::Serialize) -> std::io::Result<()> {
    let json = serde_json::to_string(message).expect("protocol messages serialize");
    writeln!(out, "{json}")?;
    out.flush()
}

/// One job as the worker sends it to its process.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct JobOrder {
    pub frame: PathBuf,
    pub image: String,
    pub params: JobParams,
    /// Where the result JSON goes (written whole or not at all).
    pub result: PathBuf,
}

struct Progress;

impl FrameObserver for Progress {
    fn tile_done(&self, done: usize, total: usize) {
        say(&ChildLine::Tile {
            done: done as u32,
            total: total as u32,
        });
    }
}

fn say(line: &ChildLine) {
    let _ = write_line(&mut std::io::stdout().lock(), line);
}

fn fail(code: ErrorCode, message: &str) {
    say(&ChildLine::Error {
        code,
        message: message.to_string(),
    });
}

/// The next message from the parent; None when stdin closed or the line is
/// no message.
fn hear() -> Option<ParentLine> {
    let mut line = String::new();
    match std::io::stdin().read_line(&mut line) {
        Ok(0) | Err(_) => None,
        Ok(_) => serde_json::from_str(&line).ok(),
    }
}

/// The worker process: `gcp-tagger run-job`, one job per `job` line on
/// stdin until stdin closes.
pub fn child_main(args: RunJobArgs) -> ExitCode {
    if let Some(parent) = args.parent {
        // SAFETY: prctl and getppid on this process.
        unsafe {
            libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
            // The server may have died before the signal was armed.
            if libc::getppid() as u32 != parent {
                return ExitCode::from(3);
            }
        }
    }
    crate::pipeline::init_native();
    // PROJ objects are kept across the process's jobs.
    let mut transformer = Transformer::default();
    loop {
        let mut line = String::new();
        match std::io::stdin().read_line(&mut line) {
            Ok(0) | Err(_) => return ExitCode::SUCCESS,
            Ok(_) => {}
        }
        match serde_json::from_str::<ParentLine>(&line) {
            Ok(ParentLine::Job(order)) => {
                if !run_one(&order, &mut transformer) {
                    return ExitCode::from(3);
                }
            }
            Ok(ParentLine::Go { .. }) => return ExitCode::from(3),
            Err(e) => fail(ErrorCode::Internal, &format!("bad job order: {e}")),
        }
        unlimit_self();
        // Hand the job's freed heap back to the system: glibc keeps it
        // otherwise (measured: a kept worker stayed at 197 MiB after an
        // 8000x6000 frame, against the 104 MiB its idle state is counted
        // at), and the next job's reservation would come on top of it.
        // SAFETY: malloc_trim only releases free memory of this process.
        unsafe {
            libc::malloc_trim(0);
        }
    }
}

/// Runs one job; `false` when the server stopped talking mid-job. Errors
/// name the frame as the client named it, never by its path on the server.
fn run_one(order: &JobOrder, transformer: &mut Transformer) -> bool {
    let stored = order.frame.to_string_lossy().into_owned();
    let file = order
        .frame
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let named = |message: &str| {
        let named = message.replace(&stored, &order.image);
        if file.is_empty() {
            named
        } else {
            named.replace(&file, &order.image)
        }
    };
    let fail = |code: ErrorCode, message: &str| fail(code, &named(message));
    let options = match order.params.check() {
        Ok((_, options)) => options,
        Err(e) => {
            fail(ErrorCode::InvalidParameters, &e.to_string());
            return true;
        }
    };
    let frame = match open_frame(&order.frame) {
        Ok(f) => f,
        Err(e) => {
            fail(raster_code(&e), &e.to_string());
            return true;
        }
    };
    let header = frame.header().clone();
    let need = need_bytes(&header, &options, true);
    // Past u32 a frame is refused by the pixel limits the parent checks.
    let dimension = |v: usize| u32::try_from(v).unwrap_or(u32::MAX);
    say(&ChildLine::Header {
        width: dimension(header.width),
        height: dimension(header.height),
        need,
    });
    let Some(ParentLine::Go {
        data_limit,
        cpu_secs,
    }) = hear()
    else {
        return false;
    };
    limit_self(data_limit, cpu_secs);
    match detect_frame_pictured(frame, &order.image, &options, transformer, &Progress) {
        Ok((mut result, pictures)) => {
            for w in &mut result.warnings {
                *w = named(w);
                say(&ChildLine::Warning { message: w.clone() });
            }
            let bytes = serde_json::to_vec(&result).expect("results serialize");
            // Pictures first: a result on disk means its pictures are too.
            let written = write_pictures(&order.result.with_extension("pictures"), &pictures)
                .and_then(|()| write_whole(&order.result, &bytes));
            match written {
                Ok(()) => say(&ChildLine::Done {
                    targets: result.targets.len() as u32,
                    width: dimension(result.width),
                    height: dimension(result.height),
                }),
                Err(e) if is_disk_full(&e) => {
                    fail(ErrorCode::NoSpace, &format!("cannot store the result: {e}"))
                }
                Err(e) => fail(
                    ErrorCode::Internal,
                    &format!("cannot store the result: {e}"),
                ),
            }
        }
        Err(FrameError::Raster(e)) => fail(raster_code(&e), &e.to_string()),
        Err(FrameError::TooLarge(e)) => fail(ErrorCode::FrameTooLarge, &e.to_string()),
        Err(e) => fail(ErrorCode::DetectionFailed, &e.to_string()),
    }
    true
}

fn set_soft_limit(resource: libc::__rlimit_resource_t, soft: u64) {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit on this process with a valid struct. Only
    // the soft limit moves (up to the hard one), so the process can lift
    // it again for its next job.
    unsafe {
        if libc::getrlimit(resource, &mut lim) != 0 {
            return;
        }
        lim.rlim_cur = (soft as libc::rlim_t).min(lim.rlim_max);
        libc::setrlimit(resource, &lim);
    }
}

/// Soft RLIMIT_DATA: what the process holds now plus `data` more; soft
/// RLIMIT_CPU: the CPU time used so far plus `cpu` seconds (SIGXCPU).
fn limit_self(data: u64, cpu: u64) {
    let now = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmData:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        })
        .map_or(512 * MIB, |kb| kb * 1024);
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage on this process.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) };
    let used = (usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) as u64 + 1;
    set_soft_limit(libc::RLIMIT_DATA, now.saturating_add(data));
    set_soft_limit(libc::RLIMIT_CPU, used + cpu);
}

/// Lifts the soft limits back to the hard ones between jobs.
fn unlimit_self() {
    set_soft_limit(libc::RLIMIT_DATA, u64::MAX);
    set_soft_limit(libc::RLIMIT_CPU, u64::MAX);
}

/// Writes a job's pictures into `dir` (replaced whole if an earlier
/// attempt left one): `N.png` per target, `preview.jpg`.
fn write_pictures(dir: &Path, pictures: &Pictures) -> std::io::Result<()> {
    match std::fs::remove_dir_all(dir) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    std::fs::create_dir_all(dir)?;
    for (i, chip) in pictures.chips.iter().enumerate() {
        std::fs::write(dir.join(format!("{i}.png")), chip)?;
    }
    write_whole(&dir.join("preview.jpg"), &pictures.preview)
}

/// Writes `bytes` to `path` through a `.part` file renamed when whole; a
/// failed write leaves nothing behind.
fn write_whole(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension("part");
    let written = std::fs::write(&tmp, bytes)
        .and_then(|()| std::fs::File::open(&tmp)?.sync_all())
        .and_then(|()| std::fs::rename(&tmp, path));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// Whether an I/O error is the disk (or the user's quota) being full: the
/// server's condition, not the frame's.
pub fn is_disk_full(e: &std::io::Error) -> bool {
    matches!(e.raw_os_error(), Some(libc::ENOSPC) | Some(libc::EDQUOT))
        || e.kind() == std::io::ErrorKind::StorageFull
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_message_reads_back_as_written_and_stray_output_is_no_message() {
        let lines = [
            ChildLine::Header {
                width: 4000,
                height: 3000,
                need: 71303168,
            },
            ChildLine::Tile { done: 3, total: 12 },
            ChildLine::Done {
                targets: 8,
                width: 4000,
                height: 3000,
            },
            ChildLine::Error {
                code: ErrorCode::UnreadableFrame,
                message: "cannot read: truncated JPEG\nat row 1200 of 3000".into(),
            },
            ChildLine::Warning {
                message: "partial: rows 0-1199 of 3000".into(),
            },
        ];
        for line in lines {
            let mut out = Vec::new();
            write_line(&mut out, &line).unwrap();
            let text = String::from_utf8(out).unwrap();
            assert_eq!(text.matches('\n').count(), 1, "one line: {text:?}");
            assert_eq!(ChildLine::parse(text.trim_end()), Some(line));
        }
        assert_eq!(
            ChildLine::parse(r#"{"kind":"error","code":"no_such_code","message":""}"#),
            None
        );
        assert_eq!(
            ChildLine::parse(r#"{"kind":"tile","done":-1,"total":2}"#),
            None
        );
        assert_eq!(ChildLine::parse("ERROR 4: libtiff says hello"), None);
        let mut out = Vec::new();
        write_line(
            &mut out,
            &ParentLine::Go {
                data_limit: 1 << 30,
                cpu_secs: 84,
            },
        )
        .unwrap();
        assert!(matches!(
            serde_json::from_slice::<ParentLine>(&out),
            Ok(ParentLine::Go {
                data_limit: 1073741824,
                cpu_secs: 84
            })
        ));
    }
}
