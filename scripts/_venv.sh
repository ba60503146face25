# Shared by scripts/demo and scripts/test: make or update .venv next to this repo.
# Sourced, not run. Works on a fresh Debian 12 with Python 3.11 (root installs what is missing).
set -euo pipefail
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO/.venv"
EXTRAS="${RVIS_EXTRAS:-}"

apt_install() {
    # apt_install PKG...: install the Debian packages that are missing (root only).
    local missing=()
    for p in "$@"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
    [ ${#missing[@]} -eq 0 ] && return 0
    if [ "$(id -u)" != 0 ]; then
        echo "rvis setup: please install the Debian packages: ${missing[*]}" >&2
        return 1
    fi
    echo "rvis setup: apt-get install ${missing[*]}" >&2
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

pick_python() {
    for py in python3.11 python3; do
        if command -v "$py" >/dev/null 2>&1 && "$py" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then
            echo "$py"; return 0
        fi
    done
    echo "rvis setup: Python >= 3.11 not found (Debian 12: apt-get install python3)" >&2
    return 1
}

# System packages a caller asks for (RVIS_APT, e.g. scripts/test: Aravis + the PyGObject build).
# Without root they cannot be installed: say so and drop the `aravis` extra (its tests skip).
if [ -n "${RVIS_APT:-}" ]; then
    # shellcheck disable=SC2086  # a word list on purpose
    if ! apt_install $RVIS_APT; then
        echo "rvis setup: continuing without the aravis extra (Aravis camera tests are skipped)" >&2
        EXTRAS="$(echo ",$EXTRAS," | sed 's/,aravis,/,/; s/^,//; s/,$//')"
    fi
fi

PY="$(pick_python)"
if ! "$PY" -c 'import venv, ensurepip' >/dev/null 2>&1; then
    apt_install python3-venv
fi
if [ ! -x "$VENV/bin/python" ]; then
    "$PY" -m venv "$VENV"
fi
# Re-install only when the project's requirements changed.
STAMP="$VENV/.rvis-stamp"
want="$(cat "$REPO/pyproject.toml" | sha256sum | cut -c1-16)-$EXTRAS"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$want" ]; then
    "$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
    spec="$REPO"
    [ -n "$EXTRAS" ] && spec="$REPO[$EXTRAS]"
    "$VENV/bin/python" -m pip install -q -e "$spec"
    echo "$want" > "$STAMP"
fi
export PATH="$VENV/bin:$PATH"
