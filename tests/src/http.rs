//! The HTTP tests' side of the wire (and the replica benchmark's): starts the real `inssplat
//! serve` on port 0 (reading the bound address it prints), and speaks raw HTTP/1.1 over loopback, so a test can send exactly
//! the malformed bytes it means to (truncated bodies, bad headers) and read any answer.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use inssplat_proto::api::{ErrorBody, JobStatus};

/// A running `inssplat serve`; killed when dropped. Its [`Client`] methods speak to it.
pub struct Server {
    child: Child,
    client: Client,
}

/// Speaks HTTP/1.1 to one address (a server, or a proxy in front of several).
pub struct Client {
    pub addr: SocketAddr,
    /// The server's log, shown when a request fails.
    log: Option<PathBuf>,
}

impl std::ops::Deref for Server {
    type Target = Client;

    fn deref(&self) -> &Client {
        &self.client
    }
}

impl Server {
    /// Starts the service on 127.0.0.1:0 with `model`, data in `data`, plus `args`, and waits
    /// until `/ready` says yes.
    pub fn start(model: &Path, data: &Path, args: &[&str]) -> Server {
        let server = Self::spawn(model, data, args);
        server.wait_ready(Duration::from_secs(120));
        server
    }

    /// Starts the service without waiting for readiness.
    pub fn spawn(model: &Path, data: &Path, args: &[&str]) -> Server {
        Self::launch(&crate::inssplat_bin(), "127.0.0.1:0", model, data, args)
    }

    /// [`Server::start`] listening on `listen` (a replica restarted where it was, keeping its
    /// name in a shared job store).
    pub fn start_on(listen: &str, model: &Path, data: &Path, args: &[&str]) -> Server {
        Self::start_binary(&crate::inssplat_bin(), listen, model, data, args)
    }

    /// [`Server::start_on`] running the `inssplat` at `bin` (a release build, to measure).
    pub fn start_binary(
        bin: &Path,
        listen: &str,
        model: &Path,
        data: &Path,
        args: &[&str],
    ) -> Server {
        let server = Self::launch(bin, listen, model, data, args);
        server.wait_ready(Duration::from_secs(120));
        server
    }

    fn launch(bin: &Path, listen: &str, model: &Path, data: &Path, args: &[&str]) -> Server {
        std::fs::create_dir_all(data).unwrap();
        let log = data.join(format!(
            "serve-{}.log",
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos()
        ));
        let mut child = Command::new(bin)
            .args([
                "serve",
                "--listen",
                listen,
                "--model",
                model.to_str().unwrap(),
                "--data-dir",
                data.to_str().unwrap(),
            ])
            .args(["--threads", "2"])
            .args(args)
            .env_remove("INSSPLAT_API_KEY")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("start inssplat serve");
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        let first = lines.next().and_then(Result::ok).unwrap_or_else(|| {
            panic!("serve printed no address; log:\n{}", std::fs::read_to_string(&log).unwrap())
        });
        let addr = first
            .strip_prefix("listening on http://")
            .unwrap_or_else(|| panic!("unexpected first line {first:?}"))
            .parse()
            .unwrap();
        // Keep draining stdout so the server never blocks on it.
        std::thread::spawn(move || for _ in lines {});
        Server { child, client: Client { addr, log: Some(log) } }
    }

    pub fn wait_ready(&self, limit: Duration) {
        let start = Instant::now();
        loop {
            if let Ok(r) = self.try_send("GET", "/ready", &[], b"")
                && r.status == 200
            {
                return;
            }
            assert!(
                start.elapsed() < limit,
                "not ready after {limit:?}; log:\n{}",
                self.log_text()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Whether the process is still running.
    pub fn alive(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// SIGKILL, and wait for the process to be gone.
    pub fn kill9(&mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// SIGTERM, then the exit status (within `limit`).
    pub fn terminate(&mut self, limit: Duration) -> ExitStatus {
        Command::new("kill").args(["-TERM", &self.pid().to_string()]).status().unwrap();
        let start = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            assert!(
                start.elapsed() < limit,
                "still running {limit:?} after SIGTERM; log:\n{}",
                self.log_text()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Resident memory of the server process, KiB (from /proc).
    pub fn rss_kib(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.pid())).unwrap();
        let line = status.lines().find(|l| l.starts_with("VmRSS:")).unwrap();
        line.split_whitespace().nth(1).unwrap().parse().unwrap()
    }
}

impl Client {
    /// A client of `addr`.
    pub fn new(addr: SocketAddr) -> Client {
        Client { addr, log: None }
    }

    /// The server's log so far (empty when unknown).
    pub fn log_text(&self) -> String {
        self.log.as_ref().and_then(|l| std::fs::read_to_string(l).ok()).unwrap_or_default()
    }

    pub fn try_send(
        &self,
        method: &str,
        path: &str,
        headers: &[(&str, &str)],
        body: &[u8],
    ) -> std::io::Result<Response> {
        let mut head = format!(
            "{method} {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\nContent-Length: {}\r\n",
            self.addr,
            body.len()
        );
        for (k, v) in headers {
            head.push_str(&format!("{k}: {v}\r\n"));
        }
        head.push_str("\r\n");
        let mut raw = head.into_bytes();
        raw.extend_from_slice(body);
        self.try_raw(&raw)
    }

    /// Sends a request with `Content-Length` and `Connection: close` added.
    pub fn send(
        &self,
        method: &str,
        path: &str,
        headers: &[(&str, &str)],
        body: &[u8],
    ) -> Response {
        self.try_send(method, path, headers, body)
            .unwrap_or_else(|e| panic!("{method} {path}: {e}; log:\n{}", self.log_text()))
    }

    /// Sends `raw` bytes as they are and reads the answer until the server closes.
    pub fn try_raw(&self, raw: &[u8]) -> std::io::Result<Response> {
        let mut stream = TcpStream::connect(self.addr)?;
        stream.set_read_timeout(Some(Duration::from_secs(120)))?;
        // The server may answer (413) and close before reading everything: keep its answer.
        let _ = stream.write_all(raw);
        let mut bytes = Vec::new();
        stream.read_to_end(&mut bytes)?;
        Response::parse(&bytes)
    }

    pub fn get(&self, path: &str) -> Response {
        self.send("GET", path, &[], b"")
    }

    /// The status of batch job `job`.
    pub fn job(&self, job: &str) -> JobStatus {
        self.get(&format!("/v1/jobs/{job}")).json()
    }

    /// Polls batch job `job` until at least `n` of its scenes have finished: that status, or
    /// the last one read as `Err` once `limit` has passed.
    pub fn wait_job(&self, job: &str, n: usize, limit: Duration) -> Result<JobStatus, JobStatus> {
        let start = Instant::now();
        loop {
            let s = self.job(job);
            if s.done >= n {
                return Ok(s);
            }
            if start.elapsed() >= limit {
                return Err(s);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Every status that batch job `job`'s event stream sends, to its end (at least one).
    pub fn follow_job(&self, job: &str) -> Vec<JobStatus> {
        let mut events = self.events(&format!("/v1/jobs/{job}/events"), &[]);
        let mut seen = Vec::new();
        while let Some((name, data)) = events.next_event() {
            assert_eq!(name, "status");
            seen.push(serde_json::from_str(&data).unwrap());
        }
        assert!(!seen.is_empty(), "job {job}: no event");
        seen
    }

    /// Opens `path` as a server-sent event stream.
    pub fn events(&self, path: &str, headers: &[(&str, &str)]) -> Events {
        let mut stream = TcpStream::connect(self.addr).unwrap();
        stream.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
        let mut head =
            format!("GET {path} HTTP/1.1\r\nHost: {}\r\nAccept: text/event-stream\r\n", self.addr);
        for (k, v) in headers {
            head.push_str(&format!("{k}: {v}\r\n"));
        }
        head.push_str("\r\n");
        stream.write_all(head.as_bytes()).unwrap();
        let mut reader = BufReader::new(stream);
        let mut status_line = String::new();
        reader.read_line(&mut status_line).unwrap();
        assert!(status_line.contains(" 200 "), "events: {status_line}");
        let mut chunked = false;
        loop {
            let mut line = String::new();
            reader.read_line(&mut line).unwrap();
            if line == "\r\n" {
                break;
            }
            chunked |= line.to_ascii_lowercase().starts_with("transfer-encoding: chunked");
        }
        Events { reader, chunked, buffer: String::new() }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An answer.
#[derive(Debug, Clone)]
pub struct Response {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    fn parse(bytes: &[u8]) -> std::io::Result<Response> {
        let bad = |m: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, m.to_string());
        let end = bytes
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .ok_or_else(|| bad("no end of headers"))?;
        let head = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("headers not UTF-8"))?;
        let mut lines = head.split("\r\n");
        let status = lines
            .next()
            .and_then(|l| l.split(' ').nth(1))
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| bad("no status"))?;
        let headers: Vec<(String, String)> = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
            .collect();
        let mut body = bytes[end + 4..].to_vec();
        if headers.iter().any(|(k, v)| k == "transfer-encoding" && v.contains("chunked")) {
            body = dechunk(&body);
        }
        Ok(Response { status, headers, body })
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }

    pub fn json<T: serde::de::DeserializeOwned>(&self) -> T {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| {
            panic!("status {}: body is not the expected JSON ({e}): {}", self.status, self.text())
        })
    }

    /// The body as the one error shape, checking it is JSON with a non-empty message.
    pub fn error(&self) -> ErrorBody {
        assert_eq!(
            self.header("content-type"),
            Some("application/json"),
            "status {}: {}",
            self.status,
            self.text()
        );
        let e: ErrorBody = self.json();
        assert!(!e.error.is_empty() && !e.error_type.is_empty(), "{e:?}");
        e
    }
}

fn dechunk(mut body: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(eol) = body.windows(2).position(|w| w == b"\r\n") {
        let size =
            usize::from_str_radix(std::str::from_utf8(&body[..eol]).unwrap().trim(), 16).unwrap();
        if size == 0 {
            break;
        }
        out.extend_from_slice(&body[eol + 2..eol + 2 + size]);
        body = &body[eol + 2 + size + 2..];
    }
    out
}

/// A server-sent event stream.
pub struct Events {
    reader: BufReader<TcpStream>,
    chunked: bool,
    buffer: String,
}

impl Events {
    /// The next event's (name, data); `None` when the stream ends.
    pub fn next_event(&mut self) -> Option<(String, String)> {
        loop {
            if let Some(end) = self.buffer.find("\n\n") {
                let block: String = self.buffer.drain(..end + 2).collect();
                let mut name = String::from("message");
                let mut data = String::new();
                for line in block.lines() {
                    if let Some(v) = line.strip_prefix("event:") {
                        name = v.trim().to_string();
                    } else if let Some(v) = line.strip_prefix("data:") {
                        data.push_str(v.trim_start());
                    }
                }
                if data.is_empty() {
                    continue; // keep-alive comment
                }
                return Some((name, data));
            }
            let piece = self.read_piece()?;
            self.buffer.push_str(&piece);
        }
    }

    fn read_piece(&mut self) -> Option<String> {
        if !self.chunked {
            let mut line = String::new();
            return (self.reader.read_line(&mut line).ok()? > 0).then_some(line);
        }
        let mut size_line = String::new();
        if self.reader.read_line(&mut size_line).ok()? == 0 {
            return None;
        }
        let size = usize::from_str_radix(size_line.trim(), 16).ok()?;
        if size == 0 {
            return None;
        }
        let mut data = vec![0; size + 2];
        self.reader.read_exact(&mut data).ok()?;
        data.truncate(size);
        String::from_utf8(data).ok()
    }
}

/// A multipart/form-data body of `parts` (field name, file name, bytes) and its content type.
pub fn multipart(parts: &[(&str, Option<&str>, &[u8])]) -> (String, Vec<u8>) {
    let boundary = "inssplat-test-boundary-7d3f";
    let mut body = Vec::new();
    for (name, file, bytes) in parts {
        body.extend_from_slice(
            format!("--{boundary}\r\nContent-Disposition: form-data; name=\"{name}\"").as_bytes(),
        );
        if let Some(f) = file {
            body.extend_from_slice(
                format!("; filename=\"{f}\"\r\nContent-Type: application/octet-stream").as_bytes(),
            );
        }
        body.extend_from_slice(b"\r\n\r\n");
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// A `w`×`h` PNG with a pattern that depends on `seed`.
pub fn png(w: u32, h: u32, seed: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 7 + seed * 31) as u8, (y * 5 + seed * 17) as u8, ((x ^ y) + seed) as u8])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// The photos of a dataset scene's frames, PNG-encoded.
pub fn scene_photos(scene: &Path) -> Vec<Vec<u8>> {
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(scene.join("images")).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    files.iter().map(|f| std::fs::read(f).unwrap()).collect()
}

/// Latency percentile `p` (0–100) of `samples`.
pub fn percentile(samples: &[Duration], p: f64) -> Duration {
    let mut s = samples.to_vec();
    s.sort();
    s[((s.len() - 1) as f64 * p / 100.0).round() as usize]
}
