//! Compiles `proto/` with protox (no system `protoc`) and embeds the web page from `web-ui/dist`
//! when it has been built (the build never fails without it: the server then explains how to
//! build the page).
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    compile_proto(&manifest, &out);
    embed_web_ui(&manifest, &out);
}

fn compile_proto(manifest: &Path, out: &Path) {
    let proto_root = manifest.join("../../proto");
    let file = proto_root.join("haptics/v1/haptics.proto");
    println!("cargo:rerun-if-changed={}", proto_root.display());
    let fds = protox::compile([&file], [&proto_root]).unwrap_or_else(|e| panic!("proto: {e}"));
    // Kept for server reflection, so grpcurl works without the .proto file.
    std::fs::write(
        out.join("haptics_descriptor.bin"),
        prost::Message::encode_to_vec(&fds),
    )
    .unwrap();
    tonic_prost_build::configure()
        .build_client(true)
        .build_server(true)
        .compile_fds(fds)
        .unwrap_or_else(|e| panic!("tonic codegen: {e}"));
}

/// Writes `web_assets.rs`: a table of (path, bytes) with `include_bytes!` for each file of
/// `web-ui/dist`, or an empty table when the page was not built.
fn embed_web_ui(manifest: &Path, out: &Path) {
    let web = manifest.join("../../web-ui");
    let dist = web.join("dist");
    println!("cargo:rerun-if-env-changed=HAPTICS_WEB_DIST");
    let dist = std::env::var_os("HAPTICS_WEB_DIST")
        .map(PathBuf::from)
        .unwrap_or(dist);
    let mut files = Vec::new();
    if dist.is_dir() {
        println!("cargo:rerun-if-changed={}", dist.display());
        collect(&dist, &dist, &mut files);
    } else if web.is_dir() {
        // Building the page creates `dist/`, which changes `web-ui/` and reruns this script.
        println!("cargo:rerun-if-changed={}", web.display());
    }
    files.sort();
    // Snapshot the files into OUT_DIR: a page rebuilt while cargo compiles (vite empties
    // `dist/` first) then cannot break this build; the change reruns this script.
    let snapshot = out.join("web");
    let _ = std::fs::remove_dir_all(&snapshot);
    let mut code = String::from("pub static WEB_ASSETS: &[(&str, &[u8])] = &[\n");
    for (i, (rel, abs)) in files.iter().enumerate() {
        std::fs::create_dir_all(&snapshot).unwrap();
        let copy = snapshot.join(i.to_string());
        if std::fs::copy(abs, &copy).is_err() {
            continue; // deleted meanwhile
        }
        writeln!(
            code,
            "    ({rel:?}, include_bytes!({:?})),",
            copy.display().to_string()
        )
        .unwrap();
    }
    code.push_str("];\n");
    std::fs::write(out.join("web_assets.rs"), code).unwrap();
}

fn collect(root: &Path, dir: &Path, files: &mut Vec<(String, String)>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            collect(root, &path, files);
        } else if let Ok(rel) = path.strip_prefix(root) {
            let rel = rel.to_string_lossy().replace('\\', "/");
            let abs = path.canonicalize().unwrap_or(path.clone());
            files.push((rel, abs.to_string_lossy().into_owned()));
        }
    }
}
