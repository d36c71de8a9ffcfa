#!/usr/bin/env bash
# The project's test command: installs what the tests need, then checks formatting, lints and
# runs every test. Run from anywhere; it works on a fresh Debian machine with the Rust toolchain.
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages the tests need: a real gpsd for the GPS path (tests/gpsd.rs).
packages=(gpsd)
missing=()
for p in "${packages[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
    sudo_cmd=""
    [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
    $sudo_cmd apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# Python packages the tests need, in a virtual environment of the project's: pymavlink, the
# ground station of tests/gcs.rs, and pyulog, the reader of tests/export.rs, with simplekml for
# its ulog2kml (all run by the python named by UQUAD_PYTHON).
venv=target/venv
if ! "$venv/bin/python" -c "import pymavlink, pyulog, simplekml" >/dev/null 2>&1; then
    [ -x "$venv/bin/python" ] || python3 -m venv "$venv"
    "$venv/bin/python" -m pip install --quiet pymavlink==2.4.50 pyulog==1.3.0 simplekml==1.3.6
fi
export UQUAD_PYTHON="$PWD/$venv/bin/python"

rustup component add rustfmt clippy >/dev/null 2>&1 || true
cargo fmt --all -- --check
cargo clippy --all-targets --locked -- -D warnings
# The book (docs/): mdbook from crates.io, pinned; its build fails on a page SUMMARY.md names
# that is missing. tests/docs.rs checks the generated reference pages against the code.
mdbook_version=0.5.4
if ! mdbook --version 2>/dev/null | grep -q "v$mdbook_version"; then
    cargo install mdbook --version "$mdbook_version" --locked --quiet
fi
mdbook build docs
cargo test --locked
# Deployment: the systemd unit verifies cleanly; the board's build replays like x86.
deploy/verify.sh
deploy/cross-check.sh
