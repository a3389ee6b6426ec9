//! The `slim` binary: the command line in [`cli`] over the `slim` library.

#![forbid(unsafe_code)]

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
