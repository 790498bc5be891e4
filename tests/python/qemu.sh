# Sourced by tests/python/run.sh --target qemu (after the wheel is
# installed): the MuJoCo example against the module in QEMU.
check_num() { # desc value op limit
  if awk -v v="$2" -v l="$4" "BEGIN { exit !(v $3 l) }"; then ok "$1 ($2 $3 $4)"; else nok "$1 (got '$2', want $3 $4)"; fi
}
t_build=$(date +%s)
(cd "$ROOT" && nice -n 10 make -s STOCK=1) > "$results/make.log" 2>&1 || { tail -5 "$results/make.log"; nok "module build (make STOCK=1)"; finish; }
nice -n 10 bash "$ROOT/scripts/build-userspace-static.sh" > "$results/static.log" 2>&1 \
  || { tail -5 "$results/static.log"; nok "static userspace build"; finish; }
key=$(hap_keyfile "$ROOT/build/hap-test.key")
[ -n "$port" ] || port=$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
period_us=1000
end_cycle=${HAP_PY_QEMU_END_CYCLE:-6000}
t_guest=$(date +%s)
read -r qpid qlog < <(bash "$ROOT/scripts/qemu-run.sh" --background --stock --icount \
  --udp "$port:5000" --key "$key" --log "$results/guest.log" --extra "$ROOT/tests/data/press.eff:/data/effort.eff" \
  "$ROOT/tests/guest/serve.sh" "$period_us" 300)
stop_guest() { kill $(pgrep -P "$qpid" 2>/dev/null) "$qpid" 2>/dev/null; }
trap stop_guest EXIT
until_s=$(( $(date +%s) + 600 ))
while [ "$(date +%s)" -lt "$until_s" ]; do grep -q HAP-READY "$qlog" 2>/dev/null && break; kill -0 "$qpid" 2>/dev/null || break; sleep 0.2; done
grep -q HAP-READY "$qlog" || { tail -30 "$qlog"; nok "the guest did not get ready"; finish; }
echo "# FIGURE guest ready after $(( $(date +%s) - t_guest )) s (boot, insmod, bridge)"
echo "# guest kernel: $(sed -n 's/^HAPTEST-KERNEL //p' "$qlog" | tr -d '\r' | head -1)"
echo "# mode: tcg-icount, servo period $period_us us; UDP 127.0.0.1:$port -> guest:5000, authenticated"
t_prog=$(date +%s)
timeout 400 "$py" "$ROOT/tests/python/qemu_press.py" "127.0.0.1#$port?key=$key" "$end_cycle" 3 "$results" \
  > "$results/client.txt" 2> "$results/client.err"
rc=$?
sed 's/^/# client: /' "$results/client.txt"
[ "$rc" = 0 ] && ok "the MuJoCo example ran against the module (exit 0, $(( $(date +%s) - t_prog )) s)" \
  || { tail -5 "$results/client.err" | sed 's/^/# /'; nok "the MuJoCo example exited with $rc"; }
until_s=$(( $(date +%s) + 600 ))
while [ "$(date +%s)" -lt "$until_s" ]; do kill -0 "$qpid" 2>/dev/null || break; sleep 0.2; done
stop_guest
trap - EXIT
echo "# FIGURE wall time: module and static builds $((t_guest - t_build)) s, guest (boot, run, log dump) $(( $(date +%s) - t_guest )) s"
cv() { sed -n "s/^$1: //p" "$results/client.txt" | head -1; }
check_num "client: authenticated (protocol v2)" "$(cv authenticated)" '==' 1
check_num "client: the table's contact force while pressed (N)" "$(cv max_table_contact_n)" '>' 1.0
check_num "client: samples of the press" "$(cv press_samples)" '>=' 100
check_num "client: the force felt at the handle is the contact force (median error, N)" "$(cv press_felt_vs_contact_median_err_n)" '<' 0.3
check_num "client: the tool never goes through the table top (lowest tip centre above it, m; the first landing's impact sinks it a few mm)" "$(cv tool_min_z_m)" '>' 0.0
check_num "client: the lifted tool left the table (samples in the air, no contact)" "$(cv lifted_samples)" '>=' 100
between() { sed -n "/$1-BEGIN/,/$1-END/p" "$qlog" | tr -d "\r" | grep -v -- "$1-"; }
between HAP-STATS > "$results/hap_stats.txt"
between HAP-PROTO > "$results/proto_interface.txt"
between HAP-SIMLOG | sed -E 's/\[ *[0-9]+\.[0-9]+\] .*$//' | grep -E "^[A-Za-z0-9+/=]+$" | base64 -d 2>/dev/null | gzip -dc > "$results/simlog.bin" 2>/dev/null
gv() { sed -n "s/^$2: *\([^ ]*\).*/\1/p" "$results/$1" | head -1; }
echo "# module: cycles $(gv hap_stats.txt cycles), misses $(gv hap_stats.txt misses), vpr frames $(gv hap_stats.txt vpr_frames), answers sent $(gv hap_stats.txt answers_sent)"
check_num "module: a session opened" "$(gv hap_stats.txt sessions_opened)" '>=' 1
check_num "module: the session is closed at the end" "$(gv hap_stats.txt session)" '==' 0
check_num "module: no fail-safe" "$(gv hap_stats.txt fail_safe)" '==' 0
check_num "module: no more set-points than answers (the example follows the controller)" "$(gv hap_stats.txt vpr_frames)" '<=' "$(( $(gv hap_stats.txt answers_sent) + 10 ))"
check_num "bridge: authenticated (not --insecure)" "$(gv proto_interface.txt insecure)" '==' 0
check_num "bridge: no frame failed its tag" "$(gv proto_interface.txt rejected_bad_tag)" '==' 0
# The position log (LogRecord v2, Documentation/simulator.md): the coupling
# force at the handle while pressed, then its fade once the client is silent.
"$py" - "$results/simlog.bin" > "$results/simlog_press.txt" <<'PY'
import struct, sys
d = open(sys.argv[1], "rb").read()
S, LINK_FADING = 560, 1 << 8
fx = lambda r, o: struct.unpack_from("<q", r, o)[0] / 2.0**32
recs = []
for i in range(0, len(d) - S + 1, S):
    r = d[i:i + S]
    if r[:4] != b"HAPL" or struct.unpack_from("<H", r, 552)[0] == 0:
        continue
    recs.append((struct.unpack_from("<Q", r, 8)[0], struct.unpack_from("<I", r, 28)[0],
                 [fx(r, 328 + 8 * k) for k in range(3)], struct.unpack_from("<I", r, 504)[0],
                 struct.unpack_from("<H", r, 6)[0] & 1))
pressed = [f[2] for _, age, f, st, pw in recs if pw and age < 50 and f[2] >= 0.5]
# The silence: after the last record whose set-point was fresh (< 50 cycles).
streaming = [i for i, (_, age, f, st, pw) in enumerate(recs) if pw and age < 50]
last = streaming[-1] if streaming else None
fading = [i for i, (_, age, f, st, pw) in enumerate(recs) if st & LINK_FADING and pw and last is not None and i > last]
silent = [abs(f[0]) + abs(f[1]) + abs(f[2]) for _, age, f, st, pw in recs if pw and age != 0xFFFFFFFF and age >= 100]
print("session_records:", len(recs))
print("pressed_records:", len(pressed))
print("pressed_force_max_n: %.3f" % (max(pressed) if pressed else 0))
print("pressed_force_median_n: %.3f" % (sorted(pressed)[len(pressed) // 2] if pressed else 0))
print("fading_records:", len(fading))
print("force_before_silence_n: %.3f" % (recs[last][2][2] if last is not None else 0))
print("silent_records:", len(silent))
print("silent_force_max_n: %.6f" % (max(silent) if silent else -1))
PY
sed 's/^/# simlog: /' "$results/simlog_press.txt"
sv() { sed -n "s/^$1: //p" "$results/simlog_press.txt" | head -1; }
check_num "position log: records during the session" "$(sv session_records)" '>=' 500
check_num "position log: cycles the press was felt at the handle (coupling force up >= 0.5 N)" "$(sv pressed_records)" '>=' 100
check_num "position log: the coupling force at the handle while pressed (N)" "$(sv pressed_force_max_n)" '>' 1.0
check_num "position log: the watchdog faded the coupling once the client was silent (records)" "$(sv fading_records)" '>=' 1
check_num "position log: the force was there when the client went silent (N)" "$(sv force_before_silence_n)" '>' 0.5
check_num "position log: cycles with the set-point 100+ cycles old" "$(sv silent_records)" '>=' 10
check_num "position log: no coupling force once faded (N)" "$(sv silent_force_max_n)" '<' 0.001
problems=$(grep -E "$HAP_SPLAT_RE" "$qlog" || true)
[ -z "$problems" ] && ok "no kernel warning in the guest log" || nok "kernel problems: $problems"
grep -q 'HAPTEST-RESULT rc=0' "$qlog" && ok "guest side passed (a client opened and closed a session; clean stop)" || nok "guest side failed: $(grep -E 'not ok|HAPTEST-RESULT' "$qlog" | head -5)"
