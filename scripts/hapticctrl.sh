#!/bin/sh
# hapticctrl launch script (spec D9rb.2 §3.2): starts the protocol bridge
# (proto_interface) in the background, then inserts the hapticctrl kernel
# module with its parameters; `stop` reverses it cleanly.
#
# POSIX sh + busybox tools only (insmod, rmmod, kill, pidof, sleep): it runs
# inside the minimal QEMU guest.
#
# Usage:
#   hapticctrl.sh start [--period-us N] [MODULE_PARAM=VALUE ...]
#   hapticctrl.sh stop
#   hapticctrl.sh status
#
# Environment (all optional):
#   HAP_MODULE      path of hapticctrl.ko (default: first of
#                   $HERE/hapticctrl.ko, /lib/modules/hapticctrl.ko, /hapticctrl.ko,
#                   then the DKMS-installed one: /lib/modules/$(uname -r)/updates/dkms/)
#   HAP_PROTO       proto_interface executable (default: $HERE/proto_interface,
#                   else proto_interface from PATH)
#   HAP_PROTO_ARGS  extra arguments for proto_interface (e.g. "--port 5000")
#   HAP_RUN         directory for the pid and log files (default /run, else /tmp)
#
# Order on stop: write /dev/hap_stop (fail-safe: motors inhibited, power
# off), stop proto_interface (SIGTERM; it holds the module's devices open, so
# the module could not be removed before), then rmmod.

set -u

HERE=$(cd "$(dirname "$0")" && pwd)
RUN=${HAP_RUN:-/run}
[ -d "$RUN" ] && [ -w "$RUN" ] || RUN=/tmp
PIDFILE=$RUN/proto_interface.pid
LOGFILE=$RUN/proto_interface.log
MODNAME=hapticctrl

say() { echo "hapticctrl: $*"; }
die() { echo "hapticctrl: error: $*" >&2; exit 1; }

usage() {
    cat >&2 <<EOF
usage: $0 start [--period-us N] [PARAM=VALUE ...]
       $0 stop
       $0 status
EOF
    exit 2
}

find_module() {
    if [ -n "${HAP_MODULE:-}" ]; then
        [ -f "$HAP_MODULE" ] || die "HAP_MODULE=$HAP_MODULE: no such file"
        echo "$HAP_MODULE"
        return 0
    fi
    dkms=/lib/modules/$(uname -r)/updates/dkms/$MODNAME
    for m in "$HERE/$MODNAME.ko" "/lib/modules/$MODNAME.ko" "/$MODNAME.ko" "$dkms.ko" "$dkms.ko.xz" "$dkms.ko.zst"; do
        if [ -f "$m" ]; then
            echo "$m"
            return 0
        fi
    done
    die "cannot find $MODNAME.ko (set HAP_MODULE)"
}

find_proto() {
    if [ -n "${HAP_PROTO:-}" ]; then
        echo "$HAP_PROTO"
    elif [ -x "$HERE/proto_interface" ]; then
        echo "$HERE/proto_interface"
    else
        command -v proto_interface || die "cannot find proto_interface (set HAP_PROTO)"
    fi
}

module_loaded() {
    grep -q "^$MODNAME " /proc/modules 2>/dev/null
}

proto_pid() {
    if [ -f "$PIDFILE" ]; then
        pid=$(cat "$PIDFILE")
        if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
            echo "$pid"
            return 0
        fi
    fi
    return 1
}

start() {
    period=""
    params=""
    while [ $# -gt 0 ]; do
        case "$1" in
            --period-us)
                [ $# -ge 2 ] || die "--period-us needs a value"
                period=$2
                shift 2
                ;;
            --period-us=*)
                period=${1#--period-us=}
                shift
                ;;
            *=*)
                params="$params $1"
                shift
                ;;
            *)
                die "unknown argument '$1' (expected --period-us N or PARAM=VALUE)"
                ;;
        esac
    done
    if [ -n "$period" ]; then
        case "$period" in
            ''|*[!0-9]*) die "--period-us: '$period' is not a positive integer" ;;
        esac
        params="period_us=$period$params"
    fi

    module_loaded && die "$MODNAME is already loaded (run: $0 stop)"
    if pid=$(proto_pid); then
        die "proto_interface already running (pid $pid)"
    fi
    ko=$(find_module) || exit 1
    proto=$(find_proto) || exit 1

    # 1. the bridge, in the background: it waits for the module's devices.
    # shellcheck disable=SC2086
    "$proto" ${HAP_PROTO_ARGS:-} >>"$LOGFILE" 2>&1 &
    pid=$!
    echo "$pid" >"$PIDFILE"
    sleep 1
    kill -0 "$pid" 2>/dev/null || { rm -f "$PIDFILE"; die "proto_interface exited at once (see $LOGFILE)"; }
    say "proto_interface started (pid $pid, log $LOGFILE)"

    # 2. the module, with its parameters.
    # shellcheck disable=SC2086
    if ! insmod "$ko" $params; then
        kill -TERM "$pid" 2>/dev/null
        rm -f "$PIDFILE"
        die "insmod $ko$params failed"
    fi
    say "module $ko inserted${params:+ with$params}"
}

stop() {
    rc=0
    if [ -e /dev/hap_stop ]; then
        echo 1 >/dev/hap_stop 2>/dev/null && say "stop requested (fail-safe)"
    fi
    if pid=$(proto_pid); then
        kill -TERM "$pid" 2>/dev/null
        n=0
        while kill -0 "$pid" 2>/dev/null && [ $n -lt 30 ]; do
            sleep 0.1 2>/dev/null || sleep 1
            n=$((n + 1))
        done
        if kill -0 "$pid" 2>/dev/null; then
            kill -KILL "$pid" 2>/dev/null
            say "proto_interface killed (pid $pid)"
        else
            say "proto_interface stopped (pid $pid)"
        fi
    else
        say "proto_interface not running"
    fi
    rm -f "$PIDFILE"
    if module_loaded; then
        if rmmod "$MODNAME"; then
            say "module removed"
        else
            echo "hapticctrl: error: rmmod $MODNAME failed" >&2
            rc=1
        fi
    else
        say "module not loaded"
    fi
    return $rc
}

status() {
    if module_loaded; then say "module: loaded"; else say "module: not loaded"; fi
    if pid=$(proto_pid); then say "proto_interface: running (pid $pid)"; else say "proto_interface: not running"; fi
}

[ $# -ge 1 ] || usage
cmd=$1
shift
case "$cmd" in
    start) start "$@" ;;
    stop) [ $# -eq 0 ] || usage; stop ;;
    status) [ $# -eq 0 ] || usage; status ;;
    *) usage ;;
esac
