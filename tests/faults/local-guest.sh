#!/bin/sh
# In-guest side of the local boot of scripts/bench-faults.sh (debug or KASAN
# kernel, --icount): in-guest traffic only (hapdev), no host link.
#   (c') rmmod during full in-guest traffic, N_RMMOD times: refused at once
#        (EBUSY) while the writers hold the devices; writers SIGKILLed, rmmod
#        at once: a clean unload;
#   (d)  N_POWER power off/on cycles under servo, with a coupled session
#        streaming: each state read back, no fail-safe;
#   (e)  stop (/dev/hap_stop) during load (busy loops, dd, fork storm, a
#        coupled session), N_STOP times: fail-safe in order, readers see end
#        of file, clean rmmod.
#   local-guest.sh N_RMMOD N_POWER N_STOP
. /tests/lib.sh
n_rmmod=${1:-10}; n_power=${2:-100}; n_stop=${3:-3}
echo "# period ${HAP_PERIOD_US} us, mode $HAP_MODE: $n_rmmod rmmod, $n_power power cycles, $n_stop stops"

wait_for_cycles() { # MAX_CYCLES CMD...: poll every 10 cycles
  n=$(( $1 / 10 + 1 )); shift
  while [ "$n" -gt 0 ]; do "$@" && return 0; sleep_cycles 10; n=$((n - 1)); done
  return 1
}
ge() { [ "$(stat_value "$1")" -ge "$2" ] 2>/dev/null; }
loaded() { grep -q ^hapticctrl /proc/modules; }
# rmmod_retry: rmmod until it works (the killed writers' files are released
# as they exit); prints the number of refused tries.
rmmod_retry() { r=0; while [ $r -lt 200 ] && ! rmmod hapticctrl 2>/dev/null; do r=$((r + 1)); usleep 5000; done; echo $r; }
# A coupled session streaming VPr (open, impedance, power on, 1 kHz): run as
# `hapdev couple $COUPLE >/tmp/couple.out 2>&1 &` so that $! is hapdev itself.
COUPLE="couple --offset 0.01,0,0 --ms 100000000"

# --- (c') rmmod during in-guest traffic ----------------------------------------
ok=0; refused=0; unloaded=0
i=0
while [ $i -lt "$n_rmmod" ]; do
  i=$((i + 1))
  insmod $HAP_KO period_us=$HAP_PERIOD_US || { fail "(c') insmod #$i"; break; }
  echo live 0 0 0 0 0 0 >/dev/hap_effort
  hapdev $COUPLE >/tmp/couple.out 2>&1 & cp=$!
  ( while :; do hapdev send garbage 20 >/dev/null 2>&1; done ) & gp=$!
  wait_for_cycles 2000 ge vpr_frames 50 || echo "# (c') #$i: no VPr after 2000 cycles ($(cat /tmp/couple.out))"
  rmmod hapticctrl 2>/dev/null || refused=$((refused + 1))
  kill -KILL $gp $cp 2>/dev/null
  r=$(rmmod_retry)
  loaded || unloaded=$((unloaded + 1))
  wait $cp $gp 2>/dev/null
  echo "# (c') #$i: rmmod refused under traffic, unloaded after $r more tries"
done
expect "(c') rmmod under traffic refused (EBUSY) every time" "$refused" = "$n_rmmod"
expect "(c') writers killed, then rmmod at once: unloaded every time" "$unloaded" = "$n_rmmod"

# --- (d) power off/on cycles under servo -----------------------------------------
check "(d) insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
echo live 0 0 0 0 0 0 >/dev/hap_effort
hapdev $COUPLE >/tmp/couple.out 2>&1 & cp=$!
wait_for_cycles 2000 ge vpr_frames 50 && pass "(d) a coupled session streams" || fail "(d) no stream ($(cat /tmp/couple.out))"
c0=$(stat_value cycles)
bad=0; i=0
while [ $i -lt "$n_power" ]; do
  i=$((i + 1))
  echo 0 >/dev/hap_power
  wait_for_cycles 50 sh -c 'grep -q "^power=0 motors=0" /dev/hap_power' || { bad=$((bad + 1)); echo "# (d) #$i off: $(cat /dev/hap_power)"; }
  sleep_cycles 2
  echo 1 >/dev/hap_power
  wait_for_cycles 50 sh -c 'grep -q "^power=1 motors=1" /dev/hap_power' || { bad=$((bad + 1)); echo "# (d) #$i on: $(cat /dev/hap_power)"; }
  sleep_cycles 2
done
echo "# (d) $n_power off/on cycles in $(( $(stat_value cycles) - c0 )) servo cycles"
expect "(d) $n_power power off/on cycles, every state read back" "$bad" = 0
expect "(d) still running" "$(stat_value state)" = running
expect "(d) no fail-safe" "$(stat_value fail_safe)" = 0
expect "(d) powered at the end" "$(stat_value power)" = 1
check "(d) the coupled session is still alive" kill -0 $cp
kill -KILL $cp 2>/dev/null; wait $cp 2>/dev/null
r=$(rmmod_retry)
check_not "(d) rmmod (after $r tries)" loaded

# --- (e) stop during load ----------------------------------------------------------
i=0
while [ $i -lt "$n_stop" ]; do
  i=$((i + 1))
  check "(e) #$i insmod" insmod $HAP_KO period_us=$HAP_PERIOD_US
  echo live 0 0 0 0 0 0 >/dev/hap_effort
  hapdev $COUPLE >/tmp/couple.out 2>&1 & cp=$!
  loads=""
  for _ in 1 2 3; do sh -c 'while :; do :; done' & loads="$loads $!"; done
  dd if=/dev/zero of=/dev/null bs=1M 2>/dev/null & loads="$loads $!"
  sh -c 'while :; do /bin/true; done' & loads="$loads $!"
  wait_for_cycles 4000 ge vpr_frames 50 || echo "# (e) #$i: no VPr yet ($(cat /tmp/couple.out))"
  expect "(e) #$i powered by the client" "$(stat_value power)" = 1
  dmesg -c >/dev/null
  check "(e) #$i stop request under load" sh -c 'echo stop > /dev/hap_stop'
  wait_for_cycles 500 sh -c '[ "$(sed -n "s/^state: //p" /dev/hap_stats)" = fail_safe ]' && pass "(e) #$i fail-safe reached" || fail "(e) #$i no fail-safe"
  wait_for_cycles 500 sh -c 'dmesg | grep -q "fail-safe (stop_requested): done"' || true
  dmesg | sed -n 's/.*fail-safe (stop_requested): step [0-9]\/5: \([a-z_]*\).*/\1/p' | tr '\n' ',' >/tmp/order.txt
  expect "(e) #$i step order" "$(cat /tmp/order.txt)" = "inhibit_motor_commands,power_off_arm,close_protocol,stop_tasks,release_resources,"
  expect "(e) #$i arm powered off" "$(stat_value power)" = 0
  expect "(e) #$i motors inhibited" "$(stat_value motors_inhibited)" = 1
  wait_for_cycles 500 sh -c "! kill -0 $cp 2>/dev/null" && pass "(e) #$i the client saw end of file and exited" || fail "(e) #$i the client is still there"
  # shellcheck disable=SC2086
  kill -KILL $loads $cp 2>/dev/null; wait 2>/dev/null
  r=$(rmmod_retry)
  check_not "(e) #$i rmmod after the fail-safe (after $r tries)" loaded
done
finish
