#!/usr/bin/env bash
# Prints the systemd-boot entry of a root slot (tools/image/build.sh, the update tool).
#
#   tools/image/entry.sh SLOT VERSION [EXTRA_KERNEL_ARGS]
#
# The kernel command line: the slot's squashfs as the read-only root; quiet, no console on any
# display output (fbcon=map:9 maps it to a framebuffer that does not exist), the console on
# the first serial port for service staff; a panic reboots after 10 s (and counts as a failed
# boot of an update's slot). With a sort key systemd-boot orders entries newest version first,
# an entry with no tries left last: a new slot boots first, a failed one falls behind.
set -euo pipefail
slot="$1"; version="$2"; extra="${3:-}"
case "$slot" in a|b) ;; *) echo "entry.sh: slot is a or b, not $slot" >&2; exit 2 ;; esac
cat <<END
title restage $version (slot $slot)
sort-key restage
version $version
linux /restage/$slot/vmlinuz
initrd /restage/$slot/initrd
options root=PARTLABEL=restage-root-$slot rootfstype=squashfs ro quiet loglevel=3 fbcon=map:9 vt.global_cursor_default=0 console=ttyS0,115200 systemd.show_status=false rd.udev.log_level=3 udev.log_level=3 panic=10 restage.slot=$slot${extra:+ $extra}
END
