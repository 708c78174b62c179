//! docs/CLI.md is the `--help` of every command of the three binaries, generated from clap:
//! this test writes it anew and fails when the file in the tree differs, so a changed flag
//! cannot leave the reference behind. `INSSPLAT_UPDATE_DOCS=1` writes the file instead:
//! `INSSPLAT_UPDATE_DOCS=1 cargo nextest run -p inssplat-e2e -E 'test(cli_reference)'`.

use std::path::{Path, PathBuf};
use std::process::Command;

use inssplat_e2e::{inssplat_bin, inssplat_eval_bin, inssplat_train_bin};

/// `bin args... --help`, with no environment (clap shows a set variable's value).
fn help(bin: &Path, args: &[&str]) -> String {
    let out = Command::new(bin).args(args).arg("--help").env_clear().output().expect("run --help");
    assert!(
        out.status.success(),
        "{} {args:?} --help: {}",
        bin.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("UTF-8 help")
}

/// The subcommands a `--help` lists under "Commands:", `help` left out.
fn subcommands(help: &str) -> Vec<String> {
    help.lines()
        .skip_while(|l| *l != "Commands:")
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .filter(|name| name != "help")
        .collect()
}

fn reference() -> String {
    let mut out = String::from(
        "# Command-line reference\n\nGenerated from the binaries' `--help` by \
         `tests/tests/cli_reference.rs` (`INSSPLAT_UPDATE_DOCS=1` rewrites it). Every flag \
         that names an environment variable reads it when the flag is not given.\n",
    );
    let bins: [(&str, PathBuf); 3] = [
        ("inssplat", inssplat_bin()),
        ("inssplat-eval", inssplat_eval_bin()),
        ("inssplat-train", inssplat_train_bin()),
    ];
    for (name, bin) in &bins {
        let top = help(bin, &[]);
        out += &format!("\n## `{name}`\n\n```text\n{}```\n", top);
        for sub in subcommands(&top) {
            out += &format!("\n### `{name} {sub}`\n\n```text\n{}```\n", help(bin, &[&sub]));
        }
    }
    out
}

#[test]
fn cli_reference_is_the_binaries_help() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/CLI.md");
    let now = reference();
    if std::env::var_os("INSSPLAT_UPDATE_DOCS").is_some() {
        std::fs::write(&path, &now).expect("write docs/CLI.md");
        return;
    }
    let written = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        written == now,
        "docs/CLI.md is not the binaries' --help: rewrite it with \
         INSSPLAT_UPDATE_DOCS=1 cargo nextest run -p inssplat-e2e -E 'test(cli_reference)'"
    );
}
