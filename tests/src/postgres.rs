//! A real PostgreSQL server for the tests (the job store's suite and the end-to-end tests): `initdb` into a temporary folder, started on a free
//! loopback port with its socket in that folder, stopped (and the folder removed) when dropped.
//! The binaries are Debian's `postgresql` (`/usr/lib/postgresql/N/bin`, which `scripts/setup`
//! installs), else those on the PATH. PostgreSQL refuses to run as root, so under root it runs
//! as the `postgres` user that package makes.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;

pub struct TestPostgres {
    dir: tempfile::TempDir,
    bin: PathBuf,
    port: u16,
    /// The user the server runs as, when the tests run as root.
    user: Option<&'static str>,
}

impl TestPostgres {
    /// A fresh cluster, running.
    pub fn start() -> Self {
        let bin = binaries();
        let dir = tempfile::tempdir().expect("a temporary folder");
        let root = run_output(Command::new("id").arg("-u")).trim() == "0";
        let user = root.then_some("postgres");
        if let Some(user) = user {
            run(Command::new("chown").args(["-R", user]).arg(dir.path()));
        }
        let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let server = Self { dir, bin, port, user };
        let data = server.data();
        run(server
            .command("initdb")
            .args(["-U", "postgres", "--auth=trust", "--no-sync"])
            .args(["-E", "UTF8", "-D"])
            .arg(&data));
        server.pg_ctl("start");
        server
    }

    fn data(&self) -> PathBuf {
        self.dir.path().join("data")
    }

    /// `program` of the server's binaries, run as its user.
    fn command(&self, program: &str) -> Command {
        let path = self.bin.join(program);
        match self.user {
            Some(user) => {
                let mut c = Command::new("runuser");
                c.args(["-u", user, "--"]).arg(path);
                c
            }
            None => Command::new(path),
        }
    }

    fn pg_ctl(&self, action: &str) {
        let options = format!("-p {} -h 127.0.0.1 -k {} -F", self.port, self.dir.path().display());
        let log = self.dir.path().join("server.log");
        run(self
            .command("pg_ctl")
            .args(["-w", "-m", "immediate", "-D"])
            .arg(self.data())
            .args(["-o", &options, "-l"])
            .arg(log)
            .arg(action));
    }

    /// Stops the server at once, as a crash would (`pg_ctl -m immediate`).
    pub fn stop(&self) {
        self.pg_ctl("stop");
    }

    /// Starts the stopped server again, on the same port and data.
    pub fn restart(&self) {
        self.pg_ctl("start");
    }

    /// A new, empty database's URL.
    pub fn database(&self, name: &str) -> String {
        let admin = format!("postgres://postgres@127.0.0.1:{}/postgres", self.port);
        let mut client = postgres::Client::connect(&admin, postgres::NoTls).expect("connects");
        client.batch_execute(&format!("CREATE DATABASE {name}")).expect("creates the database");
        format!("postgres://postgres@127.0.0.1:{}/{name}", self.port)
    }
}

impl Drop for TestPostgres {
    fn drop(&mut self) {
        if self.data().join("postmaster.pid").exists() {
            self.pg_ctl("stop");
        }
    }
}

/// The folder of PostgreSQL's server binaries: Debian's newest, else the PATH's `initdb`'s.
fn binaries() -> PathBuf {
    let debian = Path::new("/usr/lib/postgresql");
    let newest = std::fs::read_dir(debian).ok().and_then(|entries| {
        entries
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .max()
            .map(|v| debian.join(v.to_string()).join("bin"))
    });
    newest.filter(|b| b.join("initdb").is_file()).unwrap_or_else(|| {
        let which = run_output(Command::new("sh").args(["-c", "command -v initdb"]));
        Path::new(which.trim()).parent().expect("PostgreSQL's initdb (scripts/setup)").into()
    })
}

fn run(command: &mut Command) {
    run_output(command);
}

fn run_output(command: &mut Command) -> String {
    let out = command.output().unwrap_or_else(|e| panic!("{command:?}: {e}"));
    assert!(
        out.status.success(),
        "{command:?}: {}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}
