#!/bin/sh
# Module signature enforcement (module.sig_enforce=1 on the kernel command
# line, tests/debian/packages.sh): the unsigned module and the module signed
# with a key the kernel does not trust are both refused, each for its own
# reason; the second reason shows the kernel parsed the appended signature.
. /tests/lib.sh
expect "the kernel enforces module signatures" "$(cat /sys/module/module/parameters/sig_enforce 2>/dev/null)" = Y
check_not "the unsigned module is refused" insmod $HAP_KO
check "dmesg: refused as unsigned" dmesg_has 'Loading of unsigned module is rejected'
check_not "the module signed with an unenrolled key is refused" insmod /lib/modules/hapticctrl-signed.ko
check "dmesg: refused for its unknown key (the signature was parsed)" dmesg_has 'Loading of module with unavailable key is rejected'
check_not "no hapticctrl device appeared" test -e /dev/hap_stats
finish
