#!/usr/bin/env bash
# The README's bare-Pi install, tried on an emulated Raspberry Pi OS: Debian 12 (Bookworm) arm64
# with its own Python 3.11 and numpy 1.24 from apt, edge installed from this checkout as the README
# says (a venv with --system-site-packages, pip with tools/pi-constraints.txt), then the commands a
# user runs first: edge config on config/device.toml, edge lasers off, edge doctor on the simulator,
# and a few test files. What it cannot try: picamera2 and lgpio (Raspberry Pi's own archive, not
# reachable from here) and real pins, camera and unit; and no timing under emulation means anything.
#
#   sudo tools/check_arm_install.sh [ROOT]        # ROOT: where the arm64 system goes (/tmp/edge-arm)
#
# Needs root, debootstrap and qemu-user-static (apt install debootstrap qemu-user-static), a kernel
# with binfmt_misc, and the network to Debian's mirror and PyPI. The first run takes 10–20 min
# (debootstrap's second stage runs emulated); later runs reuse ROOT's system and take a few minutes.
set -euo pipefail
ROOT=${1:-/tmp/edge-arm}
REPO=$(cd "$(dirname "$0")/.." && pwd)

[ "$(id -u)" = 0 ] || { echo "check_arm_install: run as root (debootstrap, chroot, mounts)" >&2; exit 2; }
for tool in debootstrap chroot git; do
    command -v "$tool" >/dev/null || { echo "check_arm_install: $tool is missing (apt install debootstrap qemu-user-static)" >&2; exit 2; }
done
[ -x /usr/libexec/qemu-binfmt/aarch64-binfmt-P ] || [ -x /usr/bin/qemu-aarch64-static ] \
    || { echo "check_arm_install: no qemu for aarch64 (apt install qemu-user-static)" >&2; exit 2; }

# Register the emulator for arm64 binaries where nothing (systemd-binfmt) has done it.
[ -e /proc/sys/fs/binfmt_misc/register ] || mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc
if [ ! -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ]; then
    cat /usr/lib/binfmt.d/qemu-aarch64.conf > /proc/sys/fs/binfmt_misc/register
fi

if [ ! -x "$ROOT/usr/bin/python3" ]; then
    echo "== debootstrap: Debian 12 arm64 with python3, venv, pip and apt's numpy into $ROOT"
    debootstrap --arch=arm64 --variant=minbase \
        --include=python3,python3-venv,python3-pip,python3-numpy,ca-certificates \
        bookworm "$ROOT" http://deb.debian.org/debian >"$ROOT.debootstrap.log" 2>&1 \
        || { echo "check_arm_install: debootstrap failed: see $ROOT.debootstrap.log" >&2; exit 1; }
fi

cleanup() { for m in dev/pts dev proc sys; do umount "$ROOT/$m" 2>/dev/null || true; done; }
trap cleanup EXIT
mount -t proc proc "$ROOT/proc"; mount -t sysfs sys "$ROOT/sys"
mount --bind /dev "$ROOT/dev"; mount --bind /dev/pts "$ROOT/dev/pts"
cp /etc/resolv.conf "$ROOT/etc/resolv.conf"
# A site's TLS-inspecting proxy: its bundle, so that pip inside trusts what pip outside trusts.
bundle=${PIP_CERT:-/etc/ssl/certs/ca-certificates.crt}
cp "$bundle" "$ROOT/etc/ssl/certs/host-bundle.crt"

rm -rf "$ROOT/opt/edge"
git clone -q "$REPO" "$ROOT/opt/edge"

cat >"$ROOT/tmp/edge-check.sh" <<'EOF'
set -euo pipefail
cd /opt/edge
echo "== install, as the README says"
python3 -m venv --system-site-packages .venv
.venv/bin/pip install --disable-pip-version-check -q -c tools/pi-constraints.txt .
.venv/bin/pip install --disable-pip-version-check -q -c tools/pi-constraints.txt 'pytest~=9.0' hypothesis plyfile jinja2
.venv/bin/python -c "import sys, platform, numpy, cv2; print(f'{platform.machine()}: Python {sys.version.split()[0]}, numpy {numpy.__version__} from {numpy.__file__}, OpenCV {cv2.__version__}')"
E=/opt/edge/.venv/bin/edge
cd /tmp
echo "== edge config --config config/device.toml"; $E config --config /opt/edge/config/device.toml | head -1
echo "== edge lasers off (simulator)"; $E lasers off
echo "== edge doctor (simulator, no broker)"; $E doctor --set mqtt.enabled=false
echo "== tests (the pure core, the light commands, the doctor)"
cd /opt/edge
.venv/bin/python -m pytest -q -p no:cacheprovider tests/test_vision.py tests/test_ranging.py tests/test_rig.py \
    tests/test_lasers_off.py tests/test_doctor.py tests/test_doctor_install.py tests/test_config.py \
    tests/test_grid.py tests/test_cloud.py
EOF
chroot "$ROOT" /usr/bin/env -i PATH=/usr/bin:/bin HOME=/root OPENBLAS_NUM_THREADS=1 \
    PIP_CERT=/etc/ssl/certs/host-bundle.crt PIP_DEFAULT_TIMEOUT=180 /bin/bash /tmp/edge-check.sh
echo "check_arm_install: ok"
