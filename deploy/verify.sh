#!/usr/bin/env bash
# Checks the systemd unit against a root folder staged by install.sh, so ExecStart's binary
# exists: systemd-analyze verify (any warning fails), then systemd-analyze security
# --offline=true (an overall exposure above max_exposure, 2.0, fails; the score is printed).
# Installs Debian's systemd if missing.
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

# The sandbox: systemd-analyze rates the unit's exposure from 0.0 (sealed) to 10.0. Where
# --threshold= exists (systemd 250 and later), it counts in tenths and makes the command exit
# non-zero above it; the score line is parsed and compared as well, so the check holds on a
# version without it and a missing score line fails too.
max_exposure="2.0"
max_tenths="${max_exposure/./}"
unit="$root/etc/systemd/system/uquad.service"
threshold=()
if systemd-analyze security --help 2>&1 | grep -q -- '--threshold='; then
    threshold=(--threshold="$max_tenths")
fi
sec_rc=0
sec_out="$(SYSTEMD_COLORS=0 systemd-analyze security --offline=true --root="$root" "${threshold[@]}" \
    "$unit" 2>&1)" || sec_rc=$?
# "→ Overall exposure level for uquad.service: 1.3 OK 🙂".
score_line="$(printf '%s\n' "$sec_out" | sed -e 's/\x1b\[[0-9;]*m//g' \
    | grep -E 'Overall exposure level for uquad\.service: [0-9]+\.[0-9]' | tail -n 1 || true)"
score="$(printf '%s\n' "$score_line" \
    | sed -E -n 's/.*Overall exposure level for uquad\.service: ([0-9]+\.[0-9]).*/\1/p')"
if [ -z "$score" ]; then
    echo "deploy/verify.sh: no overall exposure in systemd-analyze security's output:" >&2
    echo "$sec_out" >&2
    exit 1
fi
score_tenths="${score/./}"
if [ "$((10#$score_tenths))" -gt "$((10#$max_tenths))" ] || [ "$sec_rc" -ne 0 ]; then
    echo "systemd-analyze security (exit $sec_rc) rates uquad.service above $max_exposure:" >&2
    printf '%s\n' "$sec_out" | grep -v '✓' >&2
    exit 1
fi
echo "deploy/verify.sh: ${score_line#*Overall } (at most $max_exposure allowed)"
