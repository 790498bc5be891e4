#!/bin/sh
# Foundation: the module loads, its devices work, the cycle timer ticks, and
# qemu: --icount --timeout 180
# it unloads cleanly. Run with --icount for exact timing.
. /tests/lib.sh
echo "# mode: $HAP_MODE"

check_not "insmod refuses period_us=50 (out of 100..=10000)" insmod $HAP_KO period_us=50
check "dmesg explains the refused period" dmesg_has 'period_us=50 out of range'
check "insmod with period_us=$HAP_PERIOD_US" insmod $HAP_KO period_us=$HAP_PERIOD_US
check "dmesg has the load line" dmesg_has "hapticctrl: loaded, period $HAP_PERIOD_US us"
check "dmesg shows hap-core's CRC-32C check value computed in the kernel" dmesg_has 'crc32c check 0xe3069283'
check "/dev/hap_stats exists" test -c /dev/hap_stats

# The timer ticks at the configured rate and SERVO follows it.
# Ticks and cycles from one snapshot each: a read costs a few ms of guest
# time on a distribution kernel, during which both counters move.
cat /dev/hap_stats >/tmp/st0; m0=$(now_ms)
sleep 1
cat /dev/hap_stats >/tmp/st1; m1=$(now_ms)
t0=$(stat_value timer_ticks /tmp/st0); c0=$(stat_value wakeup.count /tmp/st0)
t1=$(stat_value timer_ticks /tmp/st1); c1=$(stat_value wakeup.count /tmp/st1)
dt=$((m1 - m0)); ticks=$((t1 - t0)); cycles=$((c1 - c0))
echo "# ${ticks} timer ticks and ${cycles} servo cycles in ${dt} ms of guest time"
expect "the timer ticked" "$ticks" -gt 0
if [ "$HAP_MODE" = tcg-icount ] || [ "$HAP_MODE" = kvm ]; then
  # The configured rate within 5 %: ticks per elapsed ms.
  expect "timer rate >= 95 % of nominal" $((ticks * HAP_PERIOD_US / 10)) -ge $((dt * 95))
  expect "timer rate <= 105 % of nominal" $((ticks * HAP_PERIOD_US / 10)) -le $((dt * 105))
  expect "SERVO ran every tick (within 2)" $((ticks - cycles)) -le 2
  expect "SERVO ran every tick (not ahead)" $((cycles - ticks)) -le 2
else
  echo "# plain TCG: rate and per-tick checks skipped (timer lateness is emulation noise)"
  expect "SERVO ran" "$cycles" -gt 0
fi

# Device I/O: rtf_in takes whole frames only; the rest is refused and counted.
check_not "a 9-byte write to /dev/hap_rtf_in is refused" sh -c 'printf 123456789 > /dev/hap_rtf_in'
check_not "a 100-byte write is refused" dd if=/dev/zero of=/dev/hap_rtf_in bs=100 count=1
expect "both refused writes were counted" "$(stat_value rtf_in.bad_length)" = 2
for d in hap_rtf_in hap_rtf_out hap_stop hap_power hap_stats hap_hist hap_effort hap_simlog hap_fault; do
  expect "/dev/$d is mode 0600" "$(stat -c %a /dev/$d 2>/dev/null)" = 600
done
expect "stats report the configured period" "$(stat_value period_us)" = $HAP_PERIOD_US
# /dev/hap_hist: every wake-up sample is in a bucket or the overflow. The
# histogram is read first: CLOCK keeps counting, so stats' count is >= it.
cat /dev/hap_hist > /tmp/hist
hist_total=$(awk -F': ' '/^wakeup\.hist_(us\.[0-9]+|overflow)/ { n += $2 } END { print n + 0 }' /tmp/hist)
expect "/dev/hap_hist: wake-up buckets sum to hist_count" "$hist_total" = "$(awk -F': ' '/^wakeup\.hist_count/ { print $2 }' /tmp/hist)"
expect "/dev/hap_hist: wake-up samples counted" "$hist_total" -gt 0
expect "/dev/hap_hist: no more samples than /dev/hap_stats read later" "$hist_total" -le "$(stat_value wakeup.count)"
expect "/dev/hap_hist: exec and jitter series present" "$(grep -c -E '^(exec|jitter)\.hist_count: [1-9]' /tmp/hist)" = 2
expect "the controller runs" "$(stat_value state)" = running
check "rmmod" rmmod hapticctrl
check "dmesg has the unload line" dmesg_has 'hapticctrl: unloaded'
check_not "/dev/hap_stats is gone" test -e /dev/hap_stats
check "insmod again after rmmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
check "rmmod again" rmmod hapticctrl
finish
