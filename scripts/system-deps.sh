#!/usr/bin/env bash
# System libraries that the Python wheels link against but a bare Debian lacks.
# open3d's pybind module needs libGL, libgomp, libX11 and libudev (0.20 also libusb);
# matplotlib needs nothing beyond the wheel. Installs only what is missing.
set -euo pipefail

needed=()
have_lib() { ldconfig -p 2>/dev/null | grep -q "$1"; }
have_lib 'libGL.so.1 '      || needed+=(libgl1)
have_lib 'libgomp.so.1 '    || needed+=(libgomp1)
have_lib 'libX11.so.6 '     || needed+=(libx11-6)
have_lib 'libudev.so.1 '    || needed+=(libudev1)
have_lib 'libusb-1.0.so.0 ' || needed+=(libusb-1.0-0)

if ((${#needed[@]} == 0)); then
    exit 0
fi
if ! command -v apt-get >/dev/null; then
    echo "system-deps: missing ${needed[*]} and no apt-get; install them with your package manager" >&2
    exit 1
fi
sudo=""
if [[ $(id -u) -ne 0 ]]; then sudo="sudo"; fi
echo "system-deps: installing ${needed[*]}"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${needed[@]}" >/dev/null
