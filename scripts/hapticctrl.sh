#!/bin/sh
# hapticctrl launch script (spec D9rb.2 §3.2): starts the protocol bridge
# (proto_interface) in the background, then inserts the hapticctrl kernel
# module with its parameters; `stop` reverses it cleanly.
#
# POSIX sh + busybox tools only (insmod, rmmod, kill, pidof, sleep): it runs
# inside the minimal QEMU guest.
#
# Usage:
#   hapticctrl.sh start [--period-us N] [MODULE_PARAM=VALUE ...]   (N: 100..=10000 µs;
#                   arms=2: two arms, and a second bridge for arm 1)
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
#   HAP_PROTO_ARGS1 with arms=2: extra arguments for arm 1's bridge (default
#                   "--port 5001"); it serves /dev/hap1_rtf_in, /dev/hap1_rtf_out
#   HAP_RUN         directory for the pid and log files (default /run, else /tmp)
#   HAP_DEV         where the module's devices appear (default /dev; for tests)
#   HAP_KEY         the client's pre-shared key file, mode 0600 (default
#                   /etc/hapticctrl/hap.key; `hapctl keygen FILE` writes one):
#                   the bridge authenticates every datagram (protocol v2)
#   HAP_INSECURE    1: no key, unauthenticated protocol v1 (proto_interface
#                   --insecure; default 1 only if /etc/hapticctrl/insecure exists)
#   HAP_USER        USER[:GROUP] the bridge runs as once it has read its key
#                   (default: hapticctrl if /etc/passwd has that user; empty:
#                   the bridge keeps the user it was started as). The two FIFO
#                   devices get that group and mode 0660. With
#                   HAP_PROTO_ARGS="--rt-priority N" it keeps CAP_SYS_NICE,
#                   otherwise no capability.
#
# Without a key file and without HAP_INSECURE=1, start refuses.
#
# Order on stop: write /dev/hap_stop (fail-safe: motors inhibited, power
# off), stop proto_interface (SIGTERM; it holds the module's devices open, so
# the module could not be removed before), then rmmod.

set -u

HERE=$(cd "$(dirname "$0")" && pwd)
RUN=${HAP_RUN:-/run}
[ -d "$RUN" ] && [ -w "$RUN" ] || RUN=/tmp
DEV=${HAP_DEV:-/dev}
PIDFILE=$RUN/proto_interface.pid
LOGFILE=$RUN/proto_interface.log
# With arms=2, arm 1's bridge.
PIDFILE1=$RUN/proto_interface1.pid
LOGFILE1=$RUN/proto_interface1.log
MODNAME=hapticctrl

say() { echo "hapticctrl: $*"; }
die() { echo "hapticctrl: error: $*" >&2; exit 1; }

usage() {
    cat >&2 <<EOF
usage: $0 start [--period-us N (100..=10000)] [PARAM=VALUE ...]
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
    pf=${1:-$PIDFILE}
    if [ -f "$pf" ]; then
        pid=$(cat "$pf")
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
    arms=1
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
            arms=*)
                arms=${1#arms=}
                case "$arms" in 1|2) ;; *) die "arms=$arms: 1 or 2" ;; esac
                params="$params $1"
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
        # The module's range (hap_core::clock::PERIOD_MIN_US..=PERIOD_MAX_US).
        if [ "${#period}" -gt 6 ] || [ "$period" -lt 100 ] || [ "$period" -gt 10000 ]; then
            die "--period-us: $period out of range 100..=10000"
        fi
        params="period_us=$period$params"
    fi

    module_loaded && die "$MODNAME is already loaded (run: $0 stop)"
    if pid=$(proto_pid) || pid=$(proto_pid "$PIDFILE1"); then
        die "proto_interface already running (pid $pid)"
    fi
    ko=$(find_module) || exit 1
    proto=$(find_proto) || exit 1
    key=${HAP_KEY:-/etc/hapticctrl/hap.key}
    insecure=${HAP_INSECURE:-}
    [ -z "$insecure" ] && [ -f /etc/hapticctrl/insecure ] && insecure=1
    if [ -f "$key" ]; then
        auth="--key $key"
    elif [ "$insecure" = 1 ]; then
        auth="--insecure"
        echo "hapticctrl: WARNING: no key, the bridge runs UNAUTHENTICATED (protocol v1): any host that can reach its port can steer the arm" >&2
    else
        die "no key file $key (create one: hapctl keygen $key; copy it to the client) - or HAP_INSECURE=1 for unauthenticated v1"
    fi
    # Least privilege: the bridge runs as the hapticctrl user unless told
    # otherwise (HAP_USER=USER[:GROUP], or HAP_USER= to keep the user it is
    # started as). It must be able to traverse / and /dev to its devices.
    user=${HAP_USER-}
    if [ -z "${HAP_USER+x}" ] && grep -q '^hapticctrl:' /etc/passwd 2>/dev/null; then
        user=hapticctrl
    fi
    group=""
    stats="$RUN/proto_interface.stats"
    stats_arg=""
    if [ -n "$user" ]; then
        # Numeric ids from /etc/passwd and /etc/group (the bridge resolves the
        # names the same way; no NSS needed).
        uname=${user%%:*}
        uid=$(awk -F: -v n="$uname" '$1 == n { print $3; exit }' /etc/passwd 2>/dev/null)
        case "$user" in
            *:*) gname=${user#*:}; group=$(awk -F: -v n="$gname" '$1 == n { print $3; exit }' /etc/group 2>/dev/null) ;;
            *) group=$(awk -F: -v n="$uname" '$1 == n { print $4; exit }' /etc/passwd 2>/dev/null) ;;
        esac
        [ -n "$uid" ] && [ -n "$group" ] || die "HAP_USER=$user: no such user or group in /etc/passwd, /etc/group"
        # The bridge, unprivileged, rewrites its counters in a directory of
        # its own; the usual path points there.
        mkdir -p "$RUN/hapticctrl"
        chown "$uid:$group" "$RUN/hapticctrl" || die "cannot give $RUN/hapticctrl to $user"
        stats="$RUN/hapticctrl/proto_interface.stats"
        ln -sf hapticctrl/proto_interface.stats "$RUN/proto_interface.stats"
        auth="$auth --user $user"
        stats_arg="--stats-file $stats"
    fi

    # 1. the bridge, in the background: it waits for the module's devices.
    # shellcheck disable=SC2086
    "$proto" $auth $stats_arg ${HAP_PROTO_ARGS:-} >>"$LOGFILE" 2>&1 &
    pid=$!
    echo "$pid" >"$PIDFILE"
    if [ "$arms" = 2 ]; then
        # Arm 1's bridge: its own port, devices and counters.
        # shellcheck disable=SC2086
        "$proto" $auth --stats-file "${stats%.stats}1.stats" \
            --rtf-in "$DEV/hap1_rtf_in" --rtf-out "$DEV/hap1_rtf_out" \
            ${HAP_PROTO_ARGS1:---port 5001} >>"$LOGFILE1" 2>&1 &
        echo "$!" >"$PIDFILE1"
    fi
    sleep 1
    kill -0 "$pid" 2>/dev/null || { rm -f "$PIDFILE"; stop_bridge "$PIDFILE1" >/dev/null; die "proto_interface exited at once (see $LOGFILE)"; }
    say "proto_interface started (pid $pid, log $LOGFILE)"
    if [ "$arms" = 2 ]; then
        pid1=$(proto_pid "$PIDFILE1") || { stop_bridge "$PIDFILE" >/dev/null; die "arm 1's proto_interface exited at once (see $LOGFILE1)"; }
        say "arm 1's proto_interface started (pid $pid1, log $LOGFILE1)"
    fi

    # 2. the module, with its parameters.
    # shellcheck disable=SC2086
    if ! insmod "$ko" $params; then
        stop_bridge "$PIDFILE" >/dev/null
        stop_bridge "$PIDFILE1" >/dev/null
        die "insmod $ko$params failed"
    fi
    say "module $ko inserted${params:+ with$params}"
    # 3. the bridge's group may use the two FIFO devices, and nothing else.
    if [ -n "$group" ]; then
        fifos="$DEV/hap_rtf_in $DEV/hap_rtf_out"
        [ "$arms" = 2 ] && fifos="$fifos $DEV/hap1_rtf_in $DEV/hap1_rtf_out"
        for d in $fifos; do
            n=0
            while [ ! -e "$d" ] && [ $n -lt 20 ]; do sleep 0.1 2>/dev/null || sleep 1; n=$((n + 1)); done
            chgrp "$group" "$d" && chmod 0660 "$d" || die "cannot give $d to group $group"
        done
        say "bridge runs as $user; $fifos: group $group, mode 0660"
    fi
}

# stop_bridge PIDFILE: SIGTERM the bridge of PIDFILE (SIGKILL after 3 s).
stop_bridge() {
    if pid=$(proto_pid "$1"); then
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
        rm -f "$1"
        return 0
    fi
    rm -f "$1"
    return 1
}

stop() {
    rc=0
    if [ -e "$DEV/hap_stop" ]; then
        echo 1 >"$DEV/hap_stop" 2>/dev/null && say "stop requested (fail-safe)"
    fi
    stop_bridge "$PIDFILE" || say "proto_interface not running"
    stop_bridge "$PIDFILE1" || true
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
    if pid=$(proto_pid "$PIDFILE1"); then say "arm 1's proto_interface: running (pid $pid)"; fi
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
