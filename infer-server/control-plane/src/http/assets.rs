//! The page, embedded at build time from `web-ui/dist` (see build.rs). Without a built page the
//! server answers with a page that says how to build it.
use axum::http::{header, StatusCode, Uri};
use axum::response::{Html, IntoResponse, Response};

include!(concat!(env!("OUT_DIR"), "/web_assets.rs"));

pub fn page_is_embedded() -> bool {
    WEB_ASSETS.iter().any(|(path, _)| *path == "index.html")
}

pub async fn asset(uri: Uri) -> Response {
    let path = uri.path().trim_start_matches('/');
    let path = if path.is_empty() { "index.html" } else { path };
    if let Some((_, bytes)) = WEB_ASSETS.iter().find(|(p, _)| *p == path) {
        let cache = if path.starts_with("assets/") {
            // Vite names assets by content hash.
            "public, max-age=31536000, immutable"
        } else {
            "no-cache"
        };
        return (
            [
                (header::CONTENT_TYPE, mime(path)),
                (header::CACHE_CONTROL, cache),
                (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
            ],
            *bytes,
        )
            .into_response();
    }
    if path == "index.html" {
        return (StatusCode::OK, Html(NOT_BUILT)).into_response();
    }
    (StatusCode::NOT_FOUND, format!("no such file: /{path}\n")).into_response()
}

fn mime(path: &str) -> &'static str {
    match path.rsplit_once('.').map(|(_, ext)| ext) {
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("json" | "map") => "application/json",
        Some("svg") => "image/svg+xml",
        Some("png") => "image/png",
        Some("ico") => "image/x-icon",
        Some("woff2") => "font/woff2",
        Some("woff") => "font/woff",
        Some("wasm") => "application/wasm",
        Some("txt") => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}

const NOT_BUILT: &str = r#"<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>haptics: page not built</title></head>
<body style="font-family: sans-serif; max-width: 40em; margin: 3em auto">
<h1>The web page was not built into this server</h1>
<p>infer-server embeds the page from <code>web-ui/dist</code> when it is compiled, and that
folder did not exist. Build the page, then the server again:</p>
<pre>cd web-ui &amp;&amp; npm ci &amp;&amp; npm run build &amp;&amp; cd ..
cargo build --release -p infer-server</pre>
<p>The API works without the page: <a href="/api/status">/api/status</a>,
<a href="/metrics">/metrics</a>, and <code>hapticctl</code>.</p>
</body></html>
"#;
