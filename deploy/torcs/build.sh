#!/usr/bin/env bash
# `make torcs` (issue 15): TORCS 1.3.7 built from Debian's source package with our lockstep robot
# (actors/envs/torcs/robot/) and two small race-engine patches (deploy/torcs/patches/), installed
# under third_party/torcs/ with torcs-data's roads and cars linked in. Nothing system-wide but apt
# packages. Idempotent: every step checks what is already there, so a second run takes seconds.
#
#   deploy/torcs/build.sh           everything
#   deploy/torcs/build.sh prepare   apt packages, source, patches, robot copy and configure only
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/../.." && pwd)
WORK=$ROOT/third_party/torcs-src          # Debian's source tree and the build's stamps (git-ignored)
PREFIX=${GVF_TORCS_PREFIX:-$ROOT/third_party/torcs}   # the install (git-ignored); protocol.py reads the same variable
ROBOT_SRC=$ROOT/actors/envs/torcs/robot
PATCHES=$ROOT/deploy/torcs/patches
SYSTEM_DATA=/usr/share/games/torcs        # torcs-data's roads, cars and categories
STAMPS=$WORK/stamps
# The Build-Depends of Debian's torcs source package (minus debhelper, which only packaging needs),
# torcs-data, and the tools that fetch, patch and compile.
PACKAGES=(freeglut3-dev libalut-dev libgl1-mesa-dev libopenal-dev libplib-dev libpng-dev libvorbis-dev
	libx11-dev libxi-dev libxmu-dev libxrandr-dev libxrender-dev libxt-dev libxxf86vm-dev zlib1g-dev
	torcs-data dpkg-dev xz-utils patch g++ make)

say() { echo "[make torcs] $*"; }
# apt needs root; sudo where this is not root (the script itself never needs it otherwise).
as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }
sha_of() { cat "$@" | sha256sum | cut -d' ' -f1; }

ensure_packages() {
	local missing=()
	for p in "${PACKAGES[@]}"; do
		dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
	done
	local have_src=yes
	apt-cache showsrc torcs 2>/dev/null | grep -q '^Package: torcs' || have_src=no
	if [ ${#missing[@]} -eq 0 ] && { [ "$have_src" = yes ] || [ -f "$STAMPS/source" ]; }; then
		say "apt packages present"
		return
	fi
	# `apt-get source` needs a deb-src line; add one for this release's main archive if none is set.
	if ! grep -rqsE '^(deb-src|Types:.*deb-src)' /etc/apt/sources.list /etc/apt/sources.list.d/; then
		local codename
		codename=$(. /etc/os-release && echo "$VERSION_CODENAME")
		say "adding a deb-src entry for $codename"
		printf 'Types: deb-src\nURIs: http://deb.debian.org/debian\nSuites: %s\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' \
			"$codename" | as_root tee /etc/apt/sources.list.d/gvf-drive-deb-src.sources >/dev/null
	fi
	say "apt-get update, then installing: ${missing[*]:-nothing}"
	as_root apt-get update -q
	if [ ${#missing[@]} -gt 0 ]; then
		as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
	fi
}

# Debian's source: upstream 1.3.7 plus Debian's patches (gcc 6/7 and glibc fixes).
ensure_source() {
	mkdir -p "$WORK" "$STAMPS"
	local patches_sha
	patches_sha=$(sha_of "$PATCHES"/*.patch)
	# A changed patch set is applied to a fresh tree: reverse-applying an edited patch is not reliable.
	if [ -f "$STAMPS/source" ] && [ "$(cat "$STAMPS/patches" 2>/dev/null)" != "$patches_sha" ]; then
		say "patches changed: fresh source tree"
		rm -rf "$WORK"/torcs-*/ "$STAMPS"
		mkdir -p "$STAMPS"
	fi
	if [ ! -f "$STAMPS/source" ]; then
		rm -rf "$WORK"/torcs-*/
		say "apt-get source torcs (394 MB)"
		(cd "$WORK" && apt-get source -q torcs)
		# The tarballs are not needed once unpacked (apt-get source fetches them again if asked).
		rm -f "$WORK"/torcs_*.orig.tar.* "$WORK"/torcs_*.debian.tar.* "$WORK"/torcs_*.dsc
		ls -d "$WORK"/torcs-*/ | head -1 >"$STAMPS/source"
		# The tree's data/ (737 MB) duplicates torcs-data, which the install links instead; make and
		# make install never read it (only `make datainstall` does).
		rm -rf "$(cat "$STAMPS/source")data"
	fi
	SRC=$(cat "$STAMPS/source")
	SRC=${SRC%/}
	if [ ! -f "$STAMPS/patches" ]; then
		for p in "$PATCHES"/*.patch; do
			say "patching: $(basename "$p")"
			patch -d "$SRC" -p1 -N -s <"$p"
		done
		echo "$patches_sha" >"$STAMPS/patches"
	fi
}

# Our robot goes into the tree as src/drivers/gvfdrive; files are copied only when they differ, so
# make's timestamps stay right.
sync_robot() {
	local dst=$SRC/src/drivers/gvfdrive
	mkdir -p "$dst"
	for f in "$ROBOT_SRC"/Makefile "$ROBOT_SRC"/gvfdrive.cpp "$ROBOT_SRC"/gvfdrive.xml; do
		cmp -s "$f" "$dst/$(basename "$f")" || cp "$f" "$dst/"
	done
}

# TORCS's make recursion breaks under a parent make's jobserver flags; its tree builds serially.
torcs_make() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make "$@"; }

configure_tree() {
	if [ "$(cat "$STAMPS/configured" 2>/dev/null)" = "$PREFIX" ]; then
		say "configured for $PREFIX"
		return
	fi
	say "configure --prefix=$PREFIX"
	(cd "$SRC" && ./configure --prefix="$PREFIX" --x-libraries=/usr/lib/ >"$WORK/configure.log" 2>&1) ||
		{ tail -n 30 "$WORK/configure.log"; exit 1; }
	rm -f "$STAMPS/built"
	echo "$PREFIX" >"$STAMPS/configured"
}

build_and_install() {
	local robot_sha robot_make
	robot_sha=$(sha_of "$ROBOT_SRC"/Makefile "$ROBOT_SRC"/gvfdrive.cpp "$ROBOT_SRC"/gvfdrive.xml)
	robot_make=(-C "$SRC/src/drivers/gvfdrive" TORCS_BASE="$SRC" MAKE_DEFAULT="$SRC/Make-default.mk")
	if [ ! -f "$STAMPS/built" ]; then
		say "building TORCS (serial make, a minute or two)"
		local t0=$SECONDS
		(cd "$SRC" && torcs_make)
		say "built in $((SECONDS - t0)) s; installing into $PREFIX"
		(cd "$SRC" && torcs_make install)
	elif [ "$(cat "$STAMPS/built")" != "$robot_sha" ]; then
		say "robot changed: rebuilding and installing src/drivers/gvfdrive only"
		torcs_make "${robot_make[@]}"
		torcs_make "${robot_make[@]}" install
	elif [ ! -x "$PREFIX/lib/torcs/torcs-bin" ]; then
		say "installing into $PREFIX"
		(cd "$SRC" && torcs_make install)
	else
		say "built and installed"
	fi
	echo "$robot_sha" >"$STAMPS/built"
}

# The install's data folder gets torcs-data's roads, cars, categories... as links: `make install`
# writes only config/ and drivers/, and a copy of torcs-data would be 300 MB more.
link_data() {
	local data=$PREFIX/share/games/torcs
	mkdir -p "$data"
	for entry in "$SYSTEM_DATA"/*; do
		local name
		name=$(basename "$entry")
		[ -e "$data/$name" ] || [ -L "$data/$name" ] || ln -s "$entry" "$data/$name"
	done
}

check_install() {
	local missing=0
	for f in "$PREFIX/lib/torcs/torcs-bin" "$PREFIX/lib/torcs/drivers/gvfdrive/gvfdrive.so" \
		"$PREFIX/lib/torcs/modules/simu/simuv2.so" "$PREFIX/lib/torcs/modules/track/track.so" \
		"$PREFIX/share/games/torcs/drivers/gvfdrive/gvfdrive.xml" "$PREFIX/share/games/torcs/tracks/road/g-track-1/g-track-1.xml"; do
		[ -e "$f" ] || { echo "missing: $f"; missing=1; }
	done
	[ "$missing" -eq 0 ] || exit 1
	say "TORCS ready under $PREFIX"
}

ensure_packages
ensure_source
sync_robot
configure_tree
if [ "${1:-all}" = prepare ]; then
	say "prepared (no compile)"
	exit 0
fi
build_and_install
link_data
check_install
