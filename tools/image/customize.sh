#!/usr/bin/env bash
# Makes a Debian root file system the stage machine's read-only appliance root; run by
# tools/image/build.sh as an mmdebstrap customize hook (after the packages are installed,
# with /proc, /sys and /dev mounted in the root).
#
#   tools/image/customize.sh ROOT IMAGE_VERSION
set -euo pipefail
root="$1"; version="$2"
here="$(cd "$(dirname "$0")" && pwd)"
fail() { echo "customize.sh: $*" >&2; exit 1; }

# The image's own configuration files (tools/image/rootfs), owned by root and dated
# SOURCE_DATE_EPOCH: the checkout's owners and times (a clone's are the time of cloning) must
# not reach the image, nor the initramfs made from it below.
cp -R --preserve=mode,links "$here/rootfs/." "$root/"
(cd "$here/rootfs" && find . -mindepth 1 -print0) |
    (cd "$root" && xargs -0r touch --no-dereference --date="@${SOURCE_DATE_EPOCH:?}")
kver="$(ls "$root/usr/lib/modules" | sort -V | tail -n1)"
# The initramfs holds only what finds and mounts the root: the disk controllers of a small
# PC and of the emulated machine, squashfs and ext4.
printf 'MODULES=list\nCOMPRESS=zstd\n' > "$root/etc/initramfs-tools/conf.d/restage"
printf '%s\n' squashfs ext4 virtio_pci virtio_blk nvme ahci sd_mod xhci_pci usb_storage uas > "$root/etc/initramfs-tools/modules"
chroot "$root" update-initramfs -u -k "$kver" >/dev/null 2>&1 || fail "update-initramfs failed"
# No login on any display output; the serial console (ttyS0) is the service staff's.
ln -sf /dev/null "$root/etc/systemd/system/getty@.service"
ln -sf /dev/null "$root/etc/systemd/system/autovt@.service"
ln -sf /dev/null "$root/etc/systemd/system/getty-static.service"
# Nothing to download or back up on a read-only root without a network.
# (e2scrub needs LVM snapshots, which the image has not.)
for unit in apt-daily.timer apt-daily-upgrade.timer dpkg-db-backup.timer e2scrub_all.timer e2scrub_reap.service; do
    ln -sf /dev/null "$root/etc/systemd/system/$unit"
done
# A slot on trial becomes good once the appliance is ready (restage-boot-check.service).
chroot "$root" systemctl enable restage-boot-check.service >/dev/null 2>&1 || fail "cannot enable restage-boot-check.service"
chroot "$root" systemctl is-enabled -q restage-appliance.service || fail "the appliance's unit is not enabled"
# The configuration moves to the data partition; the image keeps the factory copy.
mkdir -p "$root/usr/share/factory/etc"
mv "$root/etc/restage" "$root/usr/share/factory/etc/restage"
ln -s /var/lib/restage-etc "$root/etc/restage"
mkdir -p "$root/efi"
# A USB stick is mounted at /media/stick (rootfs/usr/lib/restage/stick): the bundle inbox, and
# where service staff install updates from. The appliance, a dynamic user, writes there (it moves
# a bundle it took to installed/ or refused/) as a member of group restage-stick, made here as
# the root is read-only at run time.
mkdir -p "$root/media/stick"
chroot "$root" groupadd --system restage-stick || fail "cannot add group restage-stick"
factory="$root/usr/share/factory/etc/restage/appliance.toml"
grep -q '^# inbox_dir = ' "$factory" || fail "$factory has no inbox_dir line to set"
sed -i 's|^# inbox_dir = .*|inbox_dir = "/media/stick"|' "$factory"
echo restage-stage > "$root/etc/hostname"
# No display manager, no graphical session: the appliance owns the outputs.
chroot "$root" systemctl set-default multi-user.target >/dev/null 2>&1 || fail "cannot set the default target"
printf 'IMAGE_ID=restage\nIMAGE_VERSION=%s\n' "$version" >> "$root/usr/lib/os-release"
