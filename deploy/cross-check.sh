#!/usr/bin/env bash
# Cross-compiles uquad for the BeagleBoard (armv7-unknown-linux-gnueabihf, Debian's
# gcc-arm-linux-gnueabihf as linker), runs the replay of the 2012 flight under qemu-arm and
# requires the same bytes as the x86 build. Installs what it needs (rustup target, Debian's
# cross linker and qemu-user).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
top="$(dirname "$here")"
cd "$top"
target=armv7-unknown-linux-gnueabihf
rustup target add "$target" >/dev/null
missing=()
for p in gcc-arm-linux-gnueabihf libc6-dev-armhf-cross qemu-user; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
    sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
    $sudo_cmd apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
export CARGO_TARGET_ARMV7_UNKNOWN_LINUX_GNUEABIHF_LINKER=arm-linux-gnueabihf-gcc
cargo build --release --locked -q --target "$target"
cargo build --release --locked -q
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
args=(replay tests/data/flight-2012-05-25 --config config/flight-2012-05.toml)
RUST_LOG=warn target/release/uquad "${args[@]}" --out "$out/x86" >/dev/null
RUST_LOG=warn qemu-arm -L /usr/arm-linux-gnueabihf "target/$target/release/uquad" "${args[@]}" --out "$out/arm" >/dev/null
for f in kalman_in.log x_hat.log w.log int.log; do
    cmp "$out/x86/$f" "$out/arm/$f"
done
echo "deploy/cross-check.sh: the $target build replays the 2012 flight to the same bytes as x86"
