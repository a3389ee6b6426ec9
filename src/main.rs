//! The `slim` binary: see [`slim::cli`].

fn main() -> std::process::ExitCode {
    slim::cli::main()
}
