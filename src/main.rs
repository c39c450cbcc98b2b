//! `kpcn`: parses arguments, runs the command, reports errors. Everything else is in the library.

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = kpcn::cli::Cli::parse();
    match kpcn::cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if e.downcast_ref::<kpcn::cli::Reported>().is_none() {
                eprintln!("kpcn: error: {e:#}");
            }
            ExitCode::FAILURE
        }
    }
}
