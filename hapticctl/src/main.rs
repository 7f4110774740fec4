fn main() {
    eprintln!("hapticctl: not built yet");
    std::process::exit(2);
}
