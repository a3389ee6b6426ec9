//! The `slim` binary: the command line in [`cli`] over the `slim` library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
