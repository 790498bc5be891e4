#!/bin/sh
# qemu: --icount --timeout 300 --extra Documentation/protocol.md:/data/protocol.md
# Spec §4.1 phase 2: after power-on the servo loop couples the arm to the
# client's virtual object (VPr stream on rtf_in); answers on rtf_out carry
# the coupling wrench; bad frames are rejected and counted while the loop runs.
. /tests/lib.sh
echo "# mode: $HAP_MODE"
check "insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US

# Answers need a session; a VPr without one is refused and answered with an error.
check "a VPr frame without a session is accepted by the device" hapdev send --session 9 --seq 5 vpr 0 0 0
sleep_cycles 20
expect "rejected as no_session" "$(stat_value rejected.no_session)" = 1

# The user holds the handle (dead-man switch closed), applying no force:
# force feedback only acts on a held handle.
check "the user grips the handle (live effort, dead-man on)" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap_effort'
# Couple to an object 3 cm in front of and 2 cm above the handle, for 3 s.
hapdev couple --offset 0.03,0,0.02 --ms 3000 > /tmp/couple.txt 2>&1
rc=$?
sed 's/^/# /' /tmp/couple.txt
expect "couple session ran" "$rc" = 0
v() { sed -n "s/^$1: \([-0-9]*\).*/\1/p" /tmp/couple.txt; }
expect "answers received (>= 2/3 of the cycles in 3 s)" "$(v answers)" -ge $(( $(cycles_in 3000) * 2 / 3 ))
expect "answers marked coupled" "$(v coupled_answers)" -ge $(cycles_in 1000)
expect "the handle started ~36 mm away" "$(v first_distance_mm)" -ge 30
expect "the handle was pulled to within 5 mm" "$(v last_distance_mm)" -le 5
expect "answers carried a coupling force (mN)" "$(v max_coupling_force_mN)" -ge 100
expect "power on (the client's power request)" "$(stat_value power)" = 1
expect "frames in counted" "$(stat_value frames_in)" -ge $(( $(cycles_in 3000) * 2 / 3 ))
expect "answers sent" "$(stat_value answers_sent)" -ge $(( $(cycles_in 3000) * 2 / 3 ))
expect "no deadline miss while coupling" "$(stat_value misses)" = 0

# Hostile frames: rejected, counted, the loop keeps running.
r0=$(stat_value frames_rejected); c0=$(stat_value cycles)
check "1000 random frames of valid lengths" hapdev send garbage 1000
check "a frame with a bad CRC" hapdev send badcrc
check_not "a short frame is refused by the device" hapdev send short
sleep_cycles 200
r1=$(stat_value frames_rejected); c1=$(stat_value cycles)
expect "1001 frames rejected by PROTO_IN" $((r1 - r0)) = 1001
expect "bad CRC counted" "$(stat_value rejected.bad_crc)" -ge 1
expect "bad length refused at the device" "$(stat_value rtf_in.bad_length)" = 1
expect "the cycle kept running" $((c1 - c0)) -ge 150
expect "no deadline miss under hostile input" "$(stat_value misses)" = 0
expect "state is running" "$(stat_value state)" = running
# A retransmitted request gets its ack again, a reordered one is not
# applied over a newer request of the same setting (protocol.md §3); both
# are counted in /dev/hap_stats.
check "a session opened" hapdev send open --seq 1000 --ack
sleep_cycles 20
s=$(stat_value session)
check "a command-type request (ack requested)" hapdev send cmd none --session "$s" --seq 1002 --ack
check "the same request again, same sequence number" hapdev send cmd none --session "$s" --seq 1002 --ack
check "an older request of the same setting" hapdev send cmd impedance --session "$s" --seq 1001 --ack
sleep_cycles 20
expect "the retransmission re-acked" "$(stat_value retransmits_reacked)" = 1
expect "the reordered request superseded" "$(stat_value superseded)" = 1
# Every protocol counter protocol.md documents is in /dev/hap_stats.
sed -n '/BEGIN STATS COUNTERS/,/END STATS COUNTERS/s/^| `\([^`]*\)`.*/\1/p' /data/protocol.md > /tmp/documented
cat /dev/hap_stats > /tmp/stats.now
missing=""
while read -r k; do
  grep -q "^$k: " /tmp/stats.now || missing="$missing $k"
done < /tmp/documented
expect "protocol.md documents counters" "$(wc -l < /tmp/documented)" -ge 20
expect "every documented counter is in /dev/hap_stats" "${missing:-none}" = none
grep -E '^(frames_|rejected\.|answers_|vpr_|session)' /dev/hap_stats | sed 's/^/# stats /'
check "rmmod" rmmod hapticctrl
finish
