//! One worker process and the line protocol (docs/external.md): a request per line on its
//! stdin, records (inline or in a file) and one closing line on its stdout; its stderr is
//! kept (the last lines) for error messages.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, Command, ExitStatus, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError, channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::scratch::{self, ScratchDir};
use crate::experiment::{Ended, StartFailure, WorkerFailure};
use crate::records::{
    ChunkShape, ChunkSums, Layout, RecordError, StepSink, WireError, decode_sums, feed_file,
    parse_record_line,
};

/// Lines of a worker's stderr kept for error messages.
const STDERR_LINES: usize = 3;
/// Longest protocol line quoted in an error.
const QUOTE: usize = 120;
/// How often a wait for an answer looks whether the worker is still running: a worker that
/// exited while a process it started still holds its stdout open is noticed this soon.
const POLL: Duration = Duration::from_millis(100);
/// How long lines a worker printed before it exited may take to arrive, once it has.
const AFTER_EXIT: Duration = Duration::from_millis(200);

/// What a request asks for.
pub(super) struct Request<'a> {
    pub id: u64,
    /// `{"name": value, …}`, in parameter order.
    pub theta: &'a str,
    pub seed: u64,
    pub runs: std::ops::Range<usize>,
    pub steps: usize,
    /// Whiteness lags, which a worker summing its own records needs.
    pub lags: usize,
    /// `"lags":…,"layout":…`, for a worker that sums its own records.
    pub sums_fields: &'a str,
    /// The measurement record to replay the filter over (its path, as a JSON string): a
    /// replay request, whose runs are the record's sequences.
    pub replay: Option<&'a str>,
}

/// What a worker answered: where its runs' sums are, and whether it says it replays
/// recorded data (`"replays": true` on its closing line) rather than simulating runs.
pub(super) struct Reply {
    /// The sums of a worker that summed its own records (`None`: they went to the sink).
    pub sums: Option<ChunkSums>,
    /// The worker replays a recording: its runs do not depend on the seed.
    pub replays: bool,
}

/// How long a request may still wait for lines.
struct Wait {
    deadline: Instant,
    timeout: Duration,
    /// Set once the worker has exited: how, and when.
    exited: Option<(Ended, Instant)>,
}

/// Whether an answer goes on after a line, and what it ended with.
#[derive(Debug, Clone, PartialEq)]
enum Answer {
    More,
    /// The records went to the sink; whether the worker replays.
    Done(bool),
    /// The worker summed its own records; whether it replays.
    Sums(Box<ChunkSums>, bool),
}

/// A running worker.
pub(super) struct Worker {
    /// Which worker of the pool (0-based), for messages.
    pub index: usize,
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<std::io::Result<String>>,
    stderr: Arc<Mutex<VecDeque<String>>>,
    /// Scratch directory for records files.
    scratch: ScratchDir,
    /// When its stdin was closed.
    closed: Option<Instant>,
}

/// Longest stderr line kept, in bytes (it is quoted by its first characters anyway).
const STDERR_LINE: usize = 4096;
/// Longest line read from a worker, in bytes: an inline record of a 300-state filter's
/// P is a few MB; a worker printing without newlines must not fill the memory.
const MAX_LINE: usize = 64 << 20;

/// The next line of `r` without its newline (`None` at the end), and whether it ended
/// within `max` bytes; a longer line is cut there, and its rest left unread.
fn read_line(r: &mut impl BufRead, max: usize) -> std::io::Result<Option<(Vec<u8>, bool)>> {
    let mut buf = Vec::new();
    let n = Read::take(&mut *r, max as u64 + 1).read_until(b'\n', &mut buf)?;
    if n == 0 {
        return Ok(None);
    }
    if buf.last() == Some(&b'\n') {
        buf.pop();
        if buf.last() == Some(&b'\r') {
            buf.pop();
        }
        Ok(Some((buf, true)))
    } else {
        // The last line may end without a newline; only an overlong one is cut.
        let whole = buf.len() <= max;
        buf.truncate(max);
        Ok(Some((buf, whole)))
    }
}

/// Read past the rest of the current line.
fn skip_line(r: &mut impl BufRead) -> std::io::Result<()> {
    loop {
        let buf = r.fill_buf()?;
        if buf.is_empty() {
            return Ok(());
        }
        if let Some(i) = buf.iter().position(|&b| b == b'\n') {
            r.consume(i + 1);
            return Ok(());
        }
        let n = buf.len();
        r.consume(n);
    }
}

/// `line` in quotes, cut to [`QUOTE`] characters, control characters (a worker's error
/// message may hold newlines) escaped, so that the error stays on one line.
fn quote(line: &str) -> String {
    format!("'{}'", crate::records::shown_up_to(line, QUOTE))
}

/// How a worker ended ("exited with status 3").
fn ended(s: ExitStatus) -> Ended {
    match s.code() {
        Some(c) => Ended::Exited(c),
        None => Ended::Killed(s.to_string()),
    }
}

impl Worker {
    /// Start `command` in `cwd` as worker `index`.
    pub(super) fn start(
        command: &[String],
        cwd: &Path,
        index: usize,
    ) -> Result<Worker, StartFailure> {
        let scratch =
            ScratchDir::create(&format!("w{index}")).map_err(|e| StartFailure::Scratch {
                temp: std::env::temp_dir(),
                why: e.to_string(),
            })?;
        let mut cmd = Command::new(&command[0]);
        // Its own process group, so that a kill reaches what it started too (a shell
        // wrapper's interpreter, a MATLAB's helpers), not just the process autotune started.
        #[cfg(unix)]
        std::os::unix::process::CommandExt::process_group(&mut cmd, 0);
        cmd.args(&command[1..])
            .current_dir(cwd)
            .env("AUTOTUNE_WORKER", "1")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child =
            scratch::spawn_registered(&mut cmd).map_err(|e| StartFailure::Spawn(e.to_string()))?;
        let stdout = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            let mut out = BufReader::new(stdout);
            loop {
                let line = match read_line(&mut out, MAX_LINE) {
                    Ok(None) => break,
                    Ok(Some((l, true))) => String::from_utf8(l).map_err(|_| {
                        std::io::Error::new(std::io::ErrorKind::InvalidData, "a line not UTF-8")
                    }),
                    Ok(Some((_, false))) => Err(std::io::Error::new(
                        std::io::ErrorKind::InvalidData,
                        format!("a line longer than {} MB", MAX_LINE >> 20),
                    )),
                    Err(e) => Err(e),
                };
                let stop = line.is_err();
                if tx.send(line).is_err() || stop {
                    break;
                }
            }
        });
        let tail = Arc::new(Mutex::new(VecDeque::new()));
        let t = Arc::clone(&tail);
        std::thread::spawn(move || {
            let mut err = BufReader::new(stderr);
            // Only the tail is kept for messages: an overlong line by its beginning.
            while let Ok(Some((l, whole))) = read_line(&mut err, STDERR_LINE) {
                if !whole && skip_line(&mut err).is_err() {
                    break;
                }
                let line = String::from_utf8_lossy(&l).into_owned();
                if line.trim().is_empty() {
                    continue;
                }
                let mut q = t.lock().unwrap_or_else(|p| p.into_inner());
                if q.len() == STDERR_LINES {
                    q.pop_front();
                }
                q.push_back(line);
            }
        });
        Ok(Worker {
            index,
            stdin: child.stdin.take(),
            child,
            lines,
            stderr: tail,
            scratch,
            closed: None,
        })
    }

    /// The last lines of the worker's stderr, as a clause for an error message.
    pub(super) fn stderr_tail(&self) -> String {
        // Give the stderr reader a moment to catch up with a worker that just exited.
        std::thread::sleep(Duration::from_millis(50));
        let q = self.stderr.lock().unwrap_or_else(|p| p.into_inner());
        if q.is_empty() {
            "its stderr is empty".to_string()
        } else {
            let parts: Vec<String> = q.iter().map(|l| quote(l.trim_end())).collect();
            format!("its stderr ends: {}", parts.join(" | "))
        }
    }

    /// How the worker ended, if it has.
    fn exit_status(&mut self) -> Option<Ended> {
        let deadline = Instant::now() + Duration::from_millis(500);
        loop {
            match self.child.try_wait() {
                Ok(Some(s)) => return Some(ended(s)),
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                _ => return None,
            }
        }
    }

    /// Ask for the records of `req` and stream them into `sink` (an experiment of
    /// `layout`), within `timeout`; a worker that summed its records itself answers their
    /// sums instead (`Some`). The error says what went wrong, in words.
    pub(super) fn request(
        &mut self,
        req: &Request<'_>,
        layout: &Layout,
        sink: &mut dyn StepSink<Error = RecordError>,
        timeout: Duration,
    ) -> Result<Reply, WorkerFailure> {
        self.send(req)?;
        let mut wait = Wait {
            deadline: Instant::now() + timeout,
            timeout,
            exited: None,
        };
        loop {
            let line = self.next_line(&mut wait)?;
            let trimmed = line.trim();
            if trimmed.is_empty() {
                continue;
            }
            match self.answer(trimmed, req, layout, sink)? {
                Answer::More => {}
                Answer::Done(replays) => {
                    return Ok(Reply {
                        sums: None,
                        replays,
                    });
                }
                Answer::Sums(sums, replays) => {
                    return Ok(Reply {
                        sums: Some(*sums),
                        replays,
                    });
                }
            }
        }
    }

    /// Write the request line to the worker's stdin.
    fn send(&mut self, req: &Request<'_>) -> Result<(), WorkerFailure> {
        let replay = req
            .replay
            .map_or_else(String::new, |path| format!(",\"replay\":{path}"));
        let line = format!(
            "{{\"id\":{},\"theta\":{},\"seed\":{},\"runs\":[{},{}],\"steps\":{},{}{replay},\"dir\":{}}}\n",
            req.id,
            req.theta,
            req.seed,
            req.runs.start,
            req.runs.end,
            req.steps,
            req.sums_fields,
            serde_json::to_string(&self.scratch.path().to_string_lossy())
                .expect("a string serializes")
        );
        let sent = match self.stdin.as_mut() {
            Some(stdin) => stdin
                .write_all(line.as_bytes())
                .and_then(|()| stdin.flush()),
            None => Err(std::io::ErrorKind::BrokenPipe.into()),
        };
        if sent.is_err() {
            let how = self.exit_status().unwrap_or(Ended::ClosedStdin);
            return Err(WorkerFailure::GoneBeforeAsked(how));
        }
        Ok(())
    }

    /// The worker's next stdout line, waiting until `wait`'s deadline; a worker that has
    /// exited gets [`AFTER_EXIT`] for the lines it printed before.
    fn next_line(&mut self, wait: &mut Wait) -> Result<String, WorkerFailure> {
        loop {
            let now = Instant::now();
            let patience = match &wait.exited {
                Some((_, at)) => (*at + AFTER_EXIT).saturating_duration_since(now),
                None => wait.deadline.saturating_duration_since(now).min(POLL),
            };
            match self.lines.recv_timeout(patience) {
                Ok(Ok(line)) => return Ok(line),
                Ok(Err(e)) => return Err(WorkerFailure::Stdout(e.to_string())),
                Err(RecvTimeoutError::Timeout) => {
                    if let Some((how, _)) = wait.exited.take() {
                        // Its stdout is still open: a process it started holds it.
                        return Err(WorkerFailure::GoneBeforeAnswering(how));
                    }
                    if Instant::now() >= wait.deadline {
                        self.kill();
                        return Err(WorkerFailure::TimedOut {
                            seconds: wait.timeout.as_secs_f64(),
                        });
                    }
                    if let Ok(Some(s)) = self.child.try_wait() {
                        wait.exited = Some((ended(s), Instant::now()));
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    let how = self.exit_status().unwrap_or(Ended::ClosedStdout);
                    return Err(WorkerFailure::GoneBeforeAnswering(how));
                }
            }
        }
    }

    /// Act on one non-empty protocol line of the answer to `req`: an inline record goes to
    /// `sink`; a records file is read into it, and ends the answer, as `done` does.
    fn answer(
        &mut self,
        line: &str,
        req: &Request<'_>,
        layout: &Layout,
        sink: &mut dyn StepSink<Error = RecordError>,
    ) -> Result<Answer, WorkerFailure> {
        let Ok(obj) = crate::records::json_object(line) else {
            return Err(WorkerFailure::NotProtocol(quote(line)));
        };
        if obj.contains_key("run") && !obj.contains_key("id") {
            let r = parse_record_line(line, layout).map_err(WorkerFailure::InlineRecord)?;
            sink.push(r).map_err(WorkerFailure::InlineRecord)?;
            return Ok(Answer::More);
        }
        if obj.get("id").and_then(Value::as_u64) != Some(req.id) {
            return Err(WorkerFailure::WrongId {
                id: obj.get("id").map(Value::to_string),
                line: quote(line),
                request: req.id,
            });
        }
        if let Some(msg) = obj.get("error") {
            let msg = msg.as_str().map_or_else(|| msg.to_string(), str::to_string);
            return Err(WorkerFailure::Reported(quote(&msg)));
        }
        let replays = obj.get("replays").and_then(Value::as_bool) == Some(true);
        if obj.get("done").and_then(Value::as_bool) == Some(true) {
            return Ok(Answer::Done(replays));
        }
        if let Some(file) = obj.get("file") {
            let Some(file) = file.as_str() else {
                return Err(WorkerFailure::FileNotPath(quote(line)));
            };
            self.read_file(file, req, layout, sink)?;
            return Ok(Answer::Done(replays));
        }
        if let Some(sums) = obj.get("sums") {
            let Some(text) = sums.as_str() else {
                return Err(WorkerFailure::Sums(WireError::Base64(
                    "not a string".into(),
                )));
            };
            let shape = ChunkShape {
                runs: req.runs.clone(),
                steps: req.steps,
                lags: req.lags,
                n_x: layout.n_x(),
                n_z: layout.n_z(),
            };
            let sums = decode_sums(text, &shape).map_err(WorkerFailure::Sums)?;
            return Ok(Answer::Sums(Box::new(sums), replays));
        }
        Err(WorkerFailure::Unexpected(quote(line)))
    }

    /// Read the records file the worker named as `file` into `sink`, and remove it.
    fn read_file(
        &self,
        file: &str,
        req: &Request<'_>,
        layout: &Layout,
        sink: &mut dyn StepSink<Error = RecordError>,
    ) -> Result<(), WorkerFailure> {
        // Resolved and contained before anything is read or deleted: a worker's answer must
        // not make autotune touch a file it did not ask for.
        let found = self
            .scratch
            .contain(file)
            .map_err(|why| WorkerFailure::Uncontained {
                file: quote(file),
                why,
            })?;
        let read = feed_file(&found.path, layout, req.steps, req.runs.start, sink)
            .map_err(WorkerFailure::RecordsFile);
        // The scratch directory is autotune's: its files go once read.
        if found.removable {
            let _ = std::fs::remove_file(&found.path);
        }
        read
    }

    /// Close the worker's stdin, which asks it to exit; [`Drop`] waits at most a second
    /// from here. Closing every worker of a pool first lets them exit together, so a pool
    /// of workers that ignore their stdin is gone in a second, not a second each.
    pub(super) fn close(&mut self) {
        if self.stdin.take().is_some() {
            self.closed = Some(Instant::now());
        }
    }

    fn kill(&mut self) {
        self.kill_group();
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGKILL to what is left of the worker's process group.
    fn kill_group(&self) {
        #[cfg(unix)]
        if let Ok(pid) = libc::pid_t::try_from(self.child.id()) {
            // SAFETY: killpg only sends a signal; the group is the worker's own (it was
            // started as its leader), so nothing of autotune's is in it.
            unsafe {
                libc::killpg(pid, libc::SIGKILL);
            }
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        // Closing stdin asks the worker to exit; one that does not within a second is killed.
        self.close();
        let deadline = self.closed.unwrap_or_else(Instant::now) + Duration::from_secs(1);
        loop {
            match self.child.try_wait() {
                Ok(Some(_)) | Err(_) => break,
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(10))
                }
                Ok(None) => {
                    self.kill();
                    break;
                }
            }
        }
        // A worker gone while a process it started lives on (one holding its stdout, a
        // daemon): its group goes with it.
        self.kill_group();
        scratch::unregister_group(self.child.id());
        // The scratch directory is removed as the field drops.
    }
}
