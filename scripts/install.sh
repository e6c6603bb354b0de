#!/usr/bin/env bash
# Installs what springc needs on a fresh Debian machine: the text-to-speech engines and ngspice
# (Debian packages, for the built-in corpus and cross-checks) and the Python package itself.
set -euo pipefail
cd "$(dirname "$0")/.."
DEBS="espeak-ng flite festival festvox-kallpc16k festvox-kdlpc16k festvox-us-slt-hts ngspice codec2 codec2-examples alsa-utils libsndfile1 sox"
missing=""
for pkg in $DEBS; do
  dpkg -s "$pkg" >/dev/null 2>&1 || missing="$missing $pkg"
done
if [ -n "$missing" ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing Debian packages:$missing"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $missing >/dev/null
  else
    echo "warning: missing Debian packages:$missing (need root and apt-get); continuing" >&2
  fi
fi
python3 -m pip install -q --disable-pip-version-check -e ".[dev]"
