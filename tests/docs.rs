//! The documentation stays true to the code: the book's reference pages are what `uquad
//! reference` writes now (a changed command, key or MAVLink handler without its page fails
//! here), and the README stays a short front door holding the two commands.

mod common;
use common::{root, uquad};

/// The first line where `a` and `b` differ, 1-based, with both lines.
fn first_difference(a: &str, b: &str) -> Option<(usize, String, String)> {
    let (mut la, mut lb) = (a.lines(), b.lines());
    for n in 1.. {
        match (la.next(), lb.next()) {
            (None, None) => return None,
            (x, y) if x == y => continue,
            (x, y) => {
                let show = |l: Option<&str>| l.unwrap_or("(the page ends)").to_string();
                return Some((n, show(x), show(y)));
            }
        }
    }
    None
}

#[test]
fn the_reference_pages_are_what_the_code_writes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("reference");
    let run = uquad(&root(), &["reference", "--out", out.to_str().unwrap()]);
    assert!(
        run.status.success(),
        "uquad reference failed: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let mut stale = Vec::new();
    for name in ["commands.md", "config.md", "mavlink.md"] {
        let fresh = std::fs::read_to_string(out.join(name)).unwrap();
        let page = root().join("docs/src/reference").join(name);
        let committed = std::fs::read_to_string(&page).unwrap_or_default();
        if let Some((line, book, code)) = first_difference(&committed, &fresh) {
            stale.push(format!(
                "{} is stale at line {line}:\n  the book: {book}\n  the code: {code}",
                page.display()
            ));
        }
    }
    assert!(
        stale.is_empty(),
        "{}\nwrite them again with `cargo run -- reference --out docs/src/reference` and commit \
         them",
        stale.join("\n")
    );
}

#[test]
fn the_readme_is_short_and_holds_the_two_commands() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(lines <= 150, "README.md has {lines} lines; at most 150");
    for command in ["cargo run --release -- sim", "tests/run.sh"] {
        assert!(
            readme.lines().any(|l| l.trim() == command),
            "README.md has no line `{command}`"
        );
    }
}

#[test]
fn every_page_of_the_book_is_in_its_summary() {
    let src = root().join("docs/src");
    let summary = std::fs::read_to_string(src.join("SUMMARY.md")).unwrap();
    let mut pages = Vec::new();
    for entry in std::fs::read_dir(&src)
        .unwrap()
        .chain(std::fs::read_dir(src.join("reference")).unwrap())
    {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "md") && !path.ends_with("SUMMARY.md") {
            pages.push(path.strip_prefix(&src).unwrap().display().to_string());
        }
    }
    assert!(pages.len() >= 10, "{pages:?}");
    for page in pages {
        assert!(
            summary.contains(&format!("]({page})")),
            "docs/src/{page} is not in SUMMARY.md: the book would not show it"
        );
    }
}
