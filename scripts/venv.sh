# Sourced by the scripts that make the oracles' Python virtual environments
# (scripts/emva-venv.sh, scripts/adctoolbox-venv.sh): one venv under target/ per oracle.
#
#   make_venv NAME IMPORT_CHECK PACKAGE...
#
# Creates $ROOT/target/NAME when it is missing or broken, installs PACKAGE... (quietly;
# all chatter goes to stderr), checks that `python -c IMPORT_CHECK` succeeds, writes a
# marker, and prints the venv's python path as the last line of stdout. Fast (no import)
# when the marker is there and the interpreter still runs (a venv breaks when the
# system python it points to changes). ROOT must be set by the caller.

make_venv() {
    local name="$1" check="$2"
    shift 2
    local venv="$ROOT/target/$name"
    local py="$venv/bin/python"
    # The marker names the packages, so a changed pin makes the venv again.
    local marker
    marker="$venv/.ok-$(printf '%s\n' "$@" | md5sum | cut -c1-12)"
    if [[ -f "$marker" && -x "$py" ]] && "$py" -c 'import sys' >/dev/null 2>&1; then
        echo "$py"
        return 0
    fi
    {
        if [[ -x "$py" ]] && "$py" -c "$check" >/dev/null 2>&1; then
            echo "$name: existing venv at $venv works"
        else
            if [[ -e "$venv" ]]; then
                echo "$name: venv at $venv is broken or incomplete; recreating it"
                rm -rf -- "$venv"
            fi
            mkdir -p "$ROOT/target"
            echo "$name: creating $venv"
            python3 -m venv "$venv"
            "$py" -m pip install --quiet --disable-pip-version-check "$@"
        fi
        if ! "$py" -c "$check"; then
            echo "$name: the check fails in $venv: $check"
            return 1
        fi
        touch "$marker"
    } 1>&2
    echo "$py"
}
