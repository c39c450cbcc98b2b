//! `kpcn completions` and `kpcn manpages`: shell completions and man pages generated from
//! the argument definitions, so they never drift from `--help`.

use clap::{Args, CommandFactory};
use clap_complete::Shell;
use std::path::PathBuf;

/// Arguments of `kpcn completions`.
#[derive(Debug, Args)]
pub struct CompletionsArgs {
    /// The shell.
    #[arg(value_enum)]
    pub shell: Shell,
}

/// Arguments of `kpcn manpages`.
#[derive(Debug, Args)]
pub struct ManpagesArgs {
    /// Folder to write `kpcn.1` and one `kpcn-COMMAND.1` per command into (created).
    pub dir: PathBuf,
}

/// Prints the completion script of a shell to stdout.
pub fn run_completions(args: &CompletionsArgs) -> anyhow::Result<()> {
    clap_complete::generate(args.shell, &mut super::Cli::command(), "kpcn", &mut std::io::stdout());
    Ok(())
}

/// Writes the man pages.
pub fn run_manpages(args: &ManpagesArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    std::fs::create_dir_all(&args.dir).with_context(|| format!("{}: cannot create the folder", args.dir.display()))?;
    clap_mangen::generate_to(super::Cli::command(), &args.dir)
        .with_context(|| format!("{}: cannot write the man pages", args.dir.display()))?;
    println!("{}", args.dir.display());
    Ok(())
}
