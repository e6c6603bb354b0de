#!/usr/bin/env bash
# Installs what springc needs on a fresh Debian machine: the text-to-speech engines and ngspice
# (Debian packages, for the built-in corpus and cross-checks), then a virtual environment (the
# first argument, default .venv) holding springc and its declared dependencies, nothing else.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${1:-.venv}"
DEBS="espeak-ng flite festival festvox-kallpc16k festvox-kdlpc16k festvox-us-slt-hts ngspice codec2 codec2-examples alsa-utils libsndfile1 sox"
python3 -c "import ensurepip, venv" 2>/dev/null || DEBS="$DEBS python3-venv"
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
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
echo "installing springc into $VENV"
"$VENV/bin/python" -m pip install -q --disable-pip-version-check -e ".[dev]"
