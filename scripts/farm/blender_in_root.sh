#!/bin/bash
# `blender` for a farm worker on this test machine: the real Blender of a Debian root filesystem
# (../shared/real-blender), with the farm folder at the same path inside as outside, so the paths
# Flamenco hands out (shared storage, render output) need no mapping.
#
#   SPLAT_FARM_ROOT=ROOT SPLAT_FARM_DIR=FARM SPLAT_FARM_HOME=HOME blender_in_root.sh ARGS...
#
# ROOT: the suite's root (root.sh sid); FARM: a folder under ROOT/io (bound at its own host path
# inside); HOME: the worker's user folder (its Blender preferences and extensions), under FARM.
# The mounts live in a mount namespace of their own: they vanish with the process, and other
# users of the same root (run.sh unmounting /proc after its command) cannot pull them away.
# `exec` all the way down: the process Flamenco starts (and signals) is Blender itself.
set -euo pipefail
root=${SPLAT_FARM_ROOT:?} farm=${SPLAT_FARM_DIR:?} home=${SPLAT_FARM_HOME:?}
command=${SPLAT_FARM_BLENDER:-blender}
exec unshare --mount --propagation private -- /bin/bash -c '
set -e
root=$1 farm=$2 home=$3 command=$4; shift 4
mount -t proc proc "$root/proc"
mount --rbind /dev "$root/dev"
mount --rbind /sys "$root/sys"
mkdir -p "$root$farm"
mount --bind "$farm" "$root$farm"
exec chroot "$root" /usr/bin/env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin HOME="$home" \
    LANG=C.UTF-8 TERM=dumb $command "$@"' blender_in_root "$root" "$farm" "$home" "$command" "$@"
