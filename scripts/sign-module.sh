#!/usr/bin/env bash
# Sign hapticctrl.ko with your own key, for a kernel that checks module
# signatures (UEFI Secure Boot with lockdown, or module.sig_enforce=1). The
# kernel accepts the module once the key's certificate is enrolled as a
# Machine Owner Key (MOK): `mokutil --import KEYDIR/hapticctrl-mok.der`, reboot,
# confirm in MokManager. See Documentation/userguide.md ("Secure Boot").
#
#   scripts/sign-module.sh --new-key [--key-dir DIR]
#       make a signing key pair: DIR/hapticctrl-mok.priv (keep it secret, 0600)
#       and DIR/hapticctrl-mok.der (the certificate to enrol); refuses to
#       overwrite an existing key
#   scripts/sign-module.sh [--key-dir DIR] [--kdir KDIR] MODULE.ko
#       sign MODULE.ko in place with the kernel's own sign-file (sha256)
#
# DIR defaults to /var/lib/hapticctrl/mok; KDIR to /lib/modules/$(uname -r)/build.
# The DKMS package does not need this script: Debian's dkms signs the
# modules it builds with its own key (/var/lib/dkms/mok.key, mok.pub).
set -euo pipefail
say() { echo "sign-module: $*" >&2; }
die() { echo "sign-module: error: $*" >&2; exit 1; }

keydir=/var/lib/hapticctrl/mok; kdir=""; new=0; ko=""
while [ $# -gt 0 ]; do
  case "$1" in
    --new-key) new=1 ;;
    --key-dir) keydir=$2; shift ;;
    --kdir) kdir=$2; shift ;;
    -h|--help) awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"; exit 0 ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) [ -z "$ko" ] || die "one module at a time"; ko=$1 ;;
  esac
  shift
done
priv=$keydir/hapticctrl-mok.priv
cert=$keydir/hapticctrl-mok.der

if [ "$new" = 1 ]; then
  [ -z "$ko" ] || die "--new-key takes no module"
  command -v openssl >/dev/null || die "openssl is not installed"
  [ ! -e "$priv" ] && [ ! -e "$cert" ] || die "$priv or $cert exists: not overwriting a key"
  mkdir -p "$keydir"; chmod 700 "$keydir"
  ( umask 077
    openssl req -new -x509 -newkey rsa:2048 -sha256 -nodes -days 36500 -batch \
      -subj "/CN=hapticctrl module signing key ($(hostname))/" \
      -addext "basicConstraints=critical,CA:FALSE" -addext "keyUsage=digitalSignature" \
      -addext "extendedKeyUsage=codeSigning" \
      -keyout "$priv" -outform DER -out "$cert" 2>/dev/null ) || die "openssl could not make the key"
  chmod 600 "$priv"; chmod 644 "$cert"
  say "key: $priv (secret), certificate: $cert"
  say "enrol it: mokutil --import $cert; reboot; choose 'Enroll MOK' in MokManager"
  exit 0
fi

[ -n "$ko" ] || die "usage: sign-module.sh [--key-dir DIR] [--kdir KDIR] MODULE.ko (or --new-key)"
[ -f "$ko" ] || die "$ko: no such file"
case "$ko" in *.ko) ;; *) die "$ko: sign the uncompressed .ko (compress afterwards if you need to)" ;; esac
[ -f "$priv" ] && [ -f "$cert" ] || die "no key in $keydir (make one with --new-key)"
kdir=${kdir:-/lib/modules/$(uname -r)/build}
sign_file=$kdir/scripts/sign-file
[ -x "$sign_file" ] || die "no $sign_file (install the kernel's headers, or give --kdir)"
hash=$(sed -n 's/^CONFIG_MODULE_SIG_HASH="\(.*\)"/\1/p' "$kdir/.config" 2>/dev/null); hash=${hash:-sha256}
if tail -c 28 "$ko" | grep -q '~Module signature appended~'; then
  die "$ko is already signed (rebuild it, then sign once)"
fi
"$sign_file" "$hash" "$priv" "$cert" "$ko" || die "sign-file failed"
tail -c 28 "$ko" | grep -q '~Module signature appended~' || die "no signature appended to $ko"
say "signed $ko ($hash) with $cert"
