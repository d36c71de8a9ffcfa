#!/usr/bin/env bash
# Installs uquad on the board: binary, configuration, systemd unit, user, udev rule.
#   deploy/install.sh [BINARY]         (as root; BINARY defaults to target/release/uquad)
#   DESTDIR=/some/root deploy/install.sh [BINARY]   stages into a root folder instead (no user
#                                                   is created, nothing is started)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
top="$(dirname "$here")"
bin="${1:-$top/target/release/uquad}"
root="${DESTDIR:-}"
[ -x "$bin" ] || { echo "install.sh: no executable at $bin (cargo build --release first)" >&2; exit 1; }

install -D -m 0755 "$bin" "$root/usr/local/bin/uquad"
install -d -m 0755 "$root/etc/uquad"
for f in "$top"/config/*; do
    if [ -f "$f" ]; then install -m 0644 "$f" "$root/etc/uquad/"; fi
done
# Missions (`uquad fly --mission /etc/uquad/missions/square.toml`).
install -d -m 0755 "$root/etc/uquad/missions"
for f in "$top"/config/missions/*.toml; do
    install -m 0644 "$f" "$root/etc/uquad/missions/"
done
# The installed profile talks to the board's devices through the stable names.
sed -i -e 's|^device = ".*"|device = "/dev/uquad-imu"|' \
       -e 's|^dir = ".*"|dir = "/var/lib/uquad/logs"|' \
       -e 's|^socket = ".*"|socket = "/var/lib/uquad/console.sock"|' "$root/etc/uquad/uquad.toml"
install -D -m 0644 "$here/uquad.service" "$root/etc/systemd/system/uquad.service"
install -D -m 0644 "$here/99-uquad.rules" "$root/etc/udev/rules.d/99-uquad.rules"
install -D -m 0644 "$top/README.md" "$root/usr/local/share/doc/uquad/README.md"
install -d -m 0750 "$root/var/lib/uquad"

if [ -z "$root" ]; then
    getent group i2c >/dev/null || groupadd --system i2c
    getent group uquad >/dev/null || groupadd --system uquad
    id uquad >/dev/null 2>&1 || useradd --system --gid uquad --groups dialout,i2c \
        --home-dir /var/lib/uquad --shell /usr/sbin/nologin uquad
    chown uquad:uquad /var/lib/uquad
    udevadm control --reload-rules && udevadm trigger || true
    systemctl daemon-reload
    echo "installed; start with: systemctl start uquad (logs: journalctl -u uquad)"
fi
