fn main() -> std::process::ExitCode {
    brightpix::cli::main()
}
