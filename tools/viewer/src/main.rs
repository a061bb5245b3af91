//! `penumbra-view`: see the crate documentation of `penumbra_view` and docs/viewer.md.

use std::process::ExitCode;

use anyhow::Result;
use clap::Parser;
use penumbra_view::options::{Args, Options};
use penumbra_view::{flight, headless, window};

fn run(args: Args) -> Result<()> {
    penumbra_cli::set_threads(args.threads)?;
    let opts = Options::resolve(args)?;
    if opts.args.headless && opts.args.flight.path.is_some() {
        let report = flight::run_headless(&opts)?;
        flight::emit(&report, opts.args.json, false)
    } else if opts.args.headless {
        let report = headless::run(&opts)?;
        if opts.args.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            headless::print_text(&report);
        }
        Ok(())
    } else {
        window::run(opts)
    }
}

fn main() -> ExitCode {
    penumbra_cli::exit_code("penumbra-view", run(Args::parse()))
}
