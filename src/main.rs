//! `kpcn`: parses arguments, runs the command, reports errors. Everything else is in the library.

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    // Rust ignores SIGPIPE, turning `kpcn info f.exr | head` into a panic; a CLI should
    // just stop, like other Unix tools.
    // SAFETY: called first thing, before any other thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = kpcn::cli::Cli::parse();
    let result = kpcn::cli::run(cli);
    if std::env::var_os(kpcn::cli::PEAK_RSS_ENV).is_some() {
        eprintln!("peak-rss-kb {}", kpcn::cli::peak_rss_kb().unwrap_or(0));
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if e.downcast_ref::<kpcn::cli::Reported>().is_none() {
                eprintln!("kpcn: error: {}", kpcn::cli::describe_error(&e));
            }
            // 2 for usage errors, as the argument parser exits; 1 for everything else.
            if e.downcast_ref::<kpcn::cli::Usage>().is_some() { ExitCode::from(2) } else { ExitCode::FAILURE }
        }
    }
}
