//! `kpcn`: parses arguments, runs the command, reports errors. Everything else is in the library.

mod cli;

use clap::Parser;
use std::process::ExitCode;

/// Large blocks on transparent huge pages: the command's fresh memory faults in 2 MiB
/// pages, not 4 KiB ones.
#[global_allocator]
static ALLOCATOR: kpcn::kernel::buffers::HugePageAllocator = kpcn::kernel::buffers::HugePageAllocator;

fn main() -> ExitCode {
    // Rust ignores SIGPIPE, turning `kpcn info f.exr | head` into a panic; a CLI should
    // just stop, like other Unix tools.
    // SAFETY: called first thing, before any other thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = cli::Cli::parse();
    let result = cli::run(cli);
    if std::env::var_os(cli::PEAK_RSS_ENV).is_some() {
        eprintln!("peak-rss-kb {}", cli::peak_rss_kb().unwrap_or(0));
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if e.downcast_ref::<cli::Reported>().is_none() {
                eprintln!("kpcn: error: {}", cli::describe_error(&e));
            }
            // 2 for usage errors, as the argument parser exits; 1 for everything else.
            if e.downcast_ref::<cli::Usage>().is_some() { ExitCode::from(2) } else { ExitCode::FAILURE }
        }
    }
}
