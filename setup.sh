#!/usr/bin/env bash
# One-step setup for a fresh Debian 12 machine (or a re-run on a set-up one):
#   - Debian packages the tests and drivers need (as root, only those missing),
#   - a virtual environment in .venv with the station installed (editable) and test tools.
# Idempotent and quiet; prints one line per step. Usage: ./setup.sh
set -euo pipefail
cd "$(dirname "$0")"

APT_PACKAGES=(socat mbpoll aravis-tools aravis-tools-cli gir1.2-aravis-0.8
              libgirepository1.0-dev libcairo2-dev pkg-config chromium iproute2 util-linux
              postgresql)

missing=()
for p in "${APT_PACKAGES[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" -eq 0 ] && command -v apt-get >/dev/null; then
        echo "setup: installing Debian packages: ${missing[*]}"
        export DEBIAN_FRONTEND=noninteractive
        # postgresql is for the tests' throw-away servers (tests/pg_server.py): no system cluster
        mkdir -p /etc/postgresql-common/createcluster.d
        echo "create_main_cluster = false" > /etc/postgresql-common/createcluster.d/station-no-main-cluster.conf
        apt-get update -qq >/dev/null
        apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    else
        echo "setup: warning: missing Debian packages (${missing[*]}); tests that need them will skip." >&2
    fi
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv with $($PY --version)"
    $PY -m venv .venv
fi
stamp=.venv/.installed-$(cat pyproject.toml | sha1sum | cut -c1-12)
if [ ! -f "$stamp" ]; then
    echo "setup: installing the station and its Python dependencies into .venv"
    .venv/bin/python -m pip install -q --upgrade pip >/dev/null
    .venv/bin/python -m pip install -q -e ".[test,shop]"
    # PyGObject for the Aravis driver builds against Debian's girepository; optional.
    if pkg-config --exists gobject-introspection-1.0 2>/dev/null; then
        .venv/bin/python -m pip install -q "pygobject<3.51" \
            || echo "setup: warning: PyGObject did not build; the Aravis driver will be unavailable." >&2
    fi
    .venv/bin/rerun analytics disable >/dev/null 2>&1 || true
    # numba compiles the rim detector's loops on their first call and caches them beside the
    # sources (station/rim/__pycache__): once here, not in the technician's first cycle
    echo "setup: compiling the rim detector's loops (once, about 10 s)"
    .venv/bin/python -c "from station.rim import detect_rim; from tests.synthetic_wheel import WheelSpec, render_wheel; detect_rim(render_wheel(WheelSpec())[0])" \
        || echo "setup: warning: the rim detector's loops did not compile now; they will at the first measurement." >&2
    rm -f .venv/.installed-*
    touch "$stamp"
fi
echo "setup: ready (.venv)"
