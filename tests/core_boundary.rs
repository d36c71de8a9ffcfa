//! Keeps the core pure: no file in `src/core` may use a tokio crate (tokio, tokio_util,
//! tokio_serial...), a clock, files, sockets or threads.

mod common;
use common::rust_files;
use std::path::Path;

#[test]
fn core_has_no_io_clock_or_runtime() {
    let forbidden = [
        // Any of the tokio crates: the runtime, its utilities, the serial port.
        "tokio",
        "std::time",
        "Instant::",
        "SystemTime",
        "std::fs",
        "std::net",
        "std::thread",
        "std::process",
        "std::io::stdin",
        "println!",
        "eprintln!",
    ];
    let mut files = Vec::new();
    rust_files(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("src/core"),
        &mut files,
    );
    assert!(files.len() >= 5, "core files found: {files:?}");
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            for bad in forbidden {
                assert!(
                    !code.contains(bad),
                    "{}:{}: the core must not use {bad}: {line}",
                    f.display(),
                    n + 1
                );
            }
        }
        assert!(
            text.starts_with("//!"),
            "{} must open with a //! header naming its spec section",
            f.display()
        );
        assert!(
            text.contains("pec"),
            "{}: the header names the spec section",
            f.display()
        );
    }
}
