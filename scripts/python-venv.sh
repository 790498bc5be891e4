# Sourced (after lib.sh) by tests/python/run.sh and scripts/bench-python.sh:
#   hap_python_venv LOGDIR   the virtual environment $HAP_CACHE/python-venv
#                            with userspace/hapticctrl-py/requirements-test.txt
#                            (re-made when that file changes); sets $venv, $py
#   hap_python_wheel LOGDIR  builds the wheel from the source tree (pip
#                            through maturin, the package's build backend)
#                            into LOGDIR/wheels and installs it; sets $whl
hap_python_venv() {
  local logdir=$1 req="$HAP_ROOT/userspace/hapticctrl-py/requirements-test.txt"
  venv="$HAP_CACHE/python-venv"; py="$venv/bin/python"
  local stamp="$venv/.requirements"
  if [ ! -x "$py" ] || ! cmp -s "$req" "$stamp"; then
    log "Python virtual environment $venv ($(grep -v '^#' "$req" | tr '\n' ' '))"
    rm -rf "$venv"
    # Debian's python3 has venv in a package of its own.
    python3 -m venv "$venv" > "$logdir/venv.log" 2>&1 || {
      rm -rf "$venv"
      [ "$(id -u)" = 0 ] && apt-get install -y -q -o DPkg::Lock::Timeout=600 python3-venv >> "$logdir/venv.log" 2>&1
      python3 -m venv "$venv" >> "$logdir/venv.log" 2>&1
    } && "$venv/bin/pip" install -q --disable-pip-version-check -r "$req" > "$logdir/pip.log" 2>&1 \
      && cp "$req" "$stamp" || { tail -5 "$logdir/pip.log"; return 1; }
  fi
  export PATH="$venv/bin:$PATH"  # maturin, for the build backend
}

hap_python_wheel() {
  local logdir=$1
  export CARGO_TARGET_DIR="$HAP_ROOT/userspace/target"
  rm -rf "$logdir/wheels"
  "$venv/bin/pip" wheel -q --disable-pip-version-check --no-deps --no-build-isolation \
    -w "$logdir/wheels" "$HAP_ROOT/userspace/hapticctrl-py" > "$logdir/wheel.log" 2>&1 \
    || { tail -20 "$logdir/wheel.log"; return 1; }
  whl=$(ls "$logdir"/wheels/hapticctrl-*.whl | head -1)
  "$venv/bin/pip" install -q --disable-pip-version-check --force-reinstall --no-deps "$whl" > "$logdir/install.log" 2>&1 \
    || { tail -5 "$logdir/install.log"; return 1; }
}
