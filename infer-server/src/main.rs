fn main() {
    eprintln!("infer-server: not built yet");
    std::process::exit(2);
}
