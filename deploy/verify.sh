#!/usr/bin/env bash
# Checks the systemd unit with systemd-analyze verify (any warning fails) against a root folder
# staged by install.sh, so ExecStart's binary exists. Installs Debian's systemd if missing.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
top="$(dirname "$here")"
if ! command -v systemd-analyze >/dev/null; then
    sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
    $sudo_cmd apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends systemd
fi
(cd "$top" && cargo build --release --locked -q)
root="$(mktemp -d)"
trap 'rm -rf "$root"' EXIT
DESTDIR="$root" "$here/install.sh" "$top/target/release/uquad"
# The system's own units (the targets every service depends on), the user and the groups.
mkdir -p "$root/usr/lib/systemd"
cp -a /usr/lib/systemd/system "$root/usr/lib/systemd/"
# The user and groups the unit names, inside the staged root.
mkdir -p "$root/etc"
printf 'root:x:0:0::/root:/bin/sh\nuquad:x:990:990::/var/lib/uquad:/usr/sbin/nologin\n' > "$root/etc/passwd"
printf 'root:x:0:\ndialout:x:20:uquad\ni2c:x:991:uquad\nuquad:x:990:\n' > "$root/etc/group"
out="$(systemd-analyze verify --root="$root" "$root/etc/systemd/system/uquad.service" 2>&1 || true)"
if [ -n "$out" ]; then
    echo "systemd-analyze verify reported:" >&2
    echo "$out" >&2
    exit 1
fi
echo "deploy/verify.sh: uquad.service verified"
