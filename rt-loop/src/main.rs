fn main() {
    eprintln!("rt-loop: not built yet");
    std::process::exit(2);
}
