fn main() {
    std::process::exit(mrbp::cli::main());
}
