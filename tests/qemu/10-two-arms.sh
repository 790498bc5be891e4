#!/bin/sh
# qemu: --icount --timeout 600
# Two arms from one controller (arms=2): each arm has its own devices
# (arm 1: /dev/hap1_*), session, coupling and motor line; one CLOCK wakes
# SERVO, which steps both in the same period. Two clients couple at once;
# one client's link loss fades only its arm; hostile frames on one arm's
# rtf_in never touch the other's counters; a stop cuts both motor lines,
# every arm's before any is powered off.
. /tests/lib.sh
echo "# mode: $HAP_MODE"
check_not "arms=3 is refused" insmod $HAP_KO period_us=$HAP_PERIOD_US arms=3
check "insmod arms=2" insmod $HAP_KO period_us=$HAP_PERIOD_US arms=2
check "dmesg: serving 2 arms" dmesg_has "serving 2 arms"
for d in hap_rtf_in hap_rtf_out hap_power hap_stats hap_effort hap_simlog \
         hap1_rtf_in hap1_rtf_out hap1_power hap1_stats hap1_effort hap1_simlog hap_stop hap_hist hap_fault; do
  check "/dev/$d exists" test -c /dev/$d
done
expect "arm 0's stats name it" "$(stat_value arm /dev/hap_stats)" = 0
expect "arm 1's stats name it" "$(stat_value arm /dev/hap1_stats)" = 1
expect "both see two arms" "$(stat_value arms /dev/hap1_stats)" = 2

check "arm 0's user grips the handle" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap_effort'
check "arm 1's user grips the handle" sh -c 'echo "live 0 0 0 0 0 0" > /dev/hap1_effort'
# Client B on arm 1 for 12 s (>= 10^4 cycles at 1 ms); client A on arm 0 stops after 3 s.
long_ms=12000
hapdev --rtf-in /dev/hap1_rtf_in --rtf-out /dev/hap1_rtf_out couple --offset 0.02,0,0.01 --ms $long_ms > /tmp/couple1.txt 2>&1 &
pid1=$!
hapdev couple --offset 0.03,0,0.02 --ms 3000 > /tmp/couple0.txt 2>&1
rc0=$?
sed 's/^/# arm 0: /' /tmp/couple0.txt
expect "arm 0's client ran" "$rc0" = 0
# Arm 0's client is silent from here on (its link is lost), arm 1's is not.
sleep 1
cat /dev/hap_stats > /tmp/s0; cat /dev/hap1_stats > /tmp/s1
st0=$(stat_value status /tmp/s0); st1=$(stat_value status /tmp/s1)
echo "# status after arm 0's link loss: arm 0 $st0, arm 1 $st1"
expect "arm 0 fades its coupling (link fading)" $(( st0 & 0x100 )) -ne 0
expect "arm 0 no longer coupled" $(( st0 & 0x80 )) = 0
expect "arm 1 still coupled" $(( st1 & 0x80 )) -ne 0
expect "arm 1 not fading" $(( st1 & 0x100 )) = 0
# Hostile frames on arm 1's rtf_in while both sessions are open.
r0=$(stat_value frames_rejected /dev/hap_stats); a0=$(stat_value frames_in /dev/hap_stats)
s0=$(stat_value sessions_opened /dev/hap_stats)
q0=$(stat_value frames_rejected /dev/hap1_stats)
check "1000 random frames into arm 1's rtf_in" hapdev --rtf-in /dev/hap1_rtf_in send garbage 1000
sleep_cycles 200
expect "arm 1 rejected them" $(( $(stat_value frames_rejected /dev/hap1_stats) - q0 )) = 1000
expect "arm 0's rejects unchanged" "$(stat_value frames_rejected /dev/hap_stats)" = "$r0"
expect "arm 0's frames unchanged" "$(stat_value frames_in /dev/hap_stats)" = "$a0"
expect "arm 0's sessions unchanged" "$(stat_value sessions_opened /dev/hap_stats)" = "$s0"
wait $pid1
rc1=$?
sed 's/^/# arm 1: /' /tmp/couple1.txt
v() { sed -n "s/^$1: \([-0-9]*\).*/\1/p" "$2"; }
expect "arm 1's client ran" "$rc1" = 0
expect "arm 0: answers marked coupled" "$(v coupled_answers /tmp/couple0.txt)" -ge $(cycles_in 1000)
expect "arm 0: handle pulled to within 5 mm" "$(v last_distance_mm /tmp/couple0.txt)" -le 5
expect "arm 1: answers (>= 2/3 of the cycles in 12 s)" "$(v answers /tmp/couple1.txt)" -ge $(( $(cycles_in $long_ms) * 2 / 3 ))
expect "arm 1: answers marked coupled" "$(v coupled_answers /tmp/couple1.txt)" -ge $(cycles_in 5000)
expect "arm 1: handle pulled to within 5 mm" "$(v last_distance_mm /tmp/couple1.txt)" -le 5
expect "one session on each arm" "$(stat_value sessions_opened /dev/hap_stats),$(stat_value sessions_opened /dev/hap1_stats)" = "1,1"
expect "both arms powered" "$(stat_value power /dev/hap_stats),$(stat_value power /dev/hap1_stats)" = "1,1"
expect "the cycles of the 12 s run (>= 10^4 at 1 ms)" "$(stat_value cycles /dev/hap_stats)" -ge $(( $(cycles_in $long_ms) * 9 / 10 ))
expect "no deadline miss with two arms" "$(stat_value misses /dev/hap_stats)" = 0

# A stop request cuts both lines: both arms inhibited (step 1) before any
# is powered off (step 2).
check "stop request" sh -c 'echo 1 > /dev/hap_stop'
sleep_cycles 50
expect "state is fail_safe" "$(stat_value state /dev/hap_stats)" = fail_safe
dmesg | sed -n 's/.*fail-safe (stop_requested): step \([0-9]\)\/5: [a-z_]* (arm \([01]\), .*gate \([a-z_]*\), supply \([01]\).*/\1 \2 \3 \4/p' > /tmp/cut.txt
sed 's/^/# step arm gate supply: /' /tmp/cut.txt
expect "step 1 inhibits arm 0, then arm 1, both still supplied" "$(sed -n 1,2p /tmp/cut.txt | tr '\n' ,)" = "1 0 fail_safe 1,1 1 fail_safe 1,"
expect "step 2 powers off arm 0, then arm 1" "$(sed -n 3,4p /tmp/cut.txt | tr '\n' ,)" = "2 0 fail_safe 0,2 1 fail_safe 0,"
expect "arm 0's line cut" "$(sed -n 's/.*gate=\([a-z_]*\).*/\1/p' /dev/hap_power)" = fail_safe
expect "arm 1's line cut" "$(sed -n 's/.*gate=\([a-z_]*\).*/\1/p' /dev/hap1_power)" = fail_safe
check "rmmod" rmmod hapticctrl
finish
