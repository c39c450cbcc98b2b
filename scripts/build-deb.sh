#!/usr/bin/env bash
# Builds the Debian package target/debian/kpcn_VERSION_ARCH.deb, with:
#   /usr/bin/kpcn                                  the command line
#   /usr/lib/TRIPLET/libkpcn.so.VERSION, .so.ABI, .so, libkpcn.a, pkgconfig/kpcn.pc
#   /usr/include/kpcn.h                            the C ABI
#   /usr/lib/TRIPLET/kpcn/oiio-plugins/kpcn.imageio.so   (OIIO_LIBRARY_PATH=that folder)
#   /usr/share/kpcn/kpcn-blender-addon.zip         (Blender: Preferences > Add-ons > Install…)
#   /usr/share/man/man1/kpcn*.1.gz                 (`kpcn manpages`)
#   bash, zsh and fish completions                 (`kpcn completions`)
# Depends is read off the files' shared libraries (dpkg -S), as dpkg-shlibdeps would.
#
#   scripts/build-deb.sh                    # then: sudo dpkg -i target/debian/kpcn_*.deb
#   KPCN_PROFILE=dev scripts/build-deb.sh   # the debug build (what the test uses)
set -euo pipefail
cd "$(dirname "$0")/.."
target=$(realpath -m "${CARGO_TARGET_DIR:-target}")
stage=$target/debian/stage
rm -rf "$stage"
# The library core (libkpcn.so.VERSION and its links, libkpcn.a, kpcn.h: scripts/install.sh
# builds and strips them), moved to the multiarch folder with a .pc of its own.
scripts/install.sh "$stage/usr"
version=$(sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n1)
abi=$(sed -n '/^\[package.metadata.kpcn\]/,/^\[/s/^abi = //p' Cargo.toml)
arch=$(dpkg --print-architecture)
triplet=$(dpkg-architecture -qDEB_HOST_MULTIARCH 2>/dev/null || gcc -print-multiarch)
lib=$stage/usr/lib/$triplet
install -d "$lib/pkgconfig" "$lib/kpcn/oiio-plugins" "$stage/DEBIAN" "$stage/usr/bin" "$stage/usr/share/kpcn" \
    "$stage/usr/share/man/man1" "$stage/usr/share/doc/kpcn" "$stage/usr/share/bash-completion/completions" \
    "$stage/usr/share/zsh/vendor-completions" "$stage/usr/share/fish/vendor_completions.d"
mv "$stage"/usr/lib/libkpcn* "$lib/"
rm -r "$stage/usr/lib/pkgconfig"

# The command, with the tools.
profile=${KPCN_PROFILE:-release}
case "$profile" in
    dev) dir=debug ;;
    *) dir=$profile ;;
esac
cargo build --locked --quiet --profile "$profile" --bin kpcn
install -m 755 "$target/$dir/kpcn" "$stage/usr/bin/kpcn"
strip --strip-debug "$stage/usr/bin/kpcn"
# A system library: on the default search path, so no rpath.
cat > "$lib/pkgconfig/kpcn.pc" <<PC
prefix=/usr
libdir=\${prefix}/lib/$triplet
includedir=\${prefix}/include

Name: kpcn
Description: Kernel-predicting Monte Carlo render denoiser (C API)
Version: $version
Requires.private: OpenImageIO >= 2.4
Libs: -L\${libdir} -lkpcn
Libs.private: -lstdc++ -lgcc_s -lutil -lrt -lpthread -lm -ldl
Cflags: -I\${includedir}
PC

# The OIIO plugin, built against the staged library and header (found at run time on the
# system's path).
pc=$target/debian/pkgconfig
mkdir -p "$pc"
sed "s|^prefix=/usr|prefix=$(cd "$stage" && pwd)/usr|" "$lib/pkgconfig/kpcn.pc" >"$pc/kpcn.pc"
PKG_CONFIG_PATH=$pc KPCN_PLUGIN_RPATH="" plugins/oiio/build.sh "$lib/kpcn/oiio-plugins" >/dev/null

(cd plugins/blender && python3 -m zipfile -c "$stage/usr/share/kpcn/kpcn-blender-addon.zip" kpcn_denoise.py)
"$stage/usr/bin/kpcn" manpages "$target/debian/man" >/dev/null
for page in "$target"/debian/man/*.1; do
    gzip -9n <"$page" >"$stage/usr/share/man/man1/$(basename "$page").gz"
done
"$stage/usr/bin/kpcn" completions bash >"$stage/usr/share/bash-completion/completions/kpcn"
"$stage/usr/bin/kpcn" completions zsh >"$stage/usr/share/zsh/vendor-completions/_kpcn"
"$stage/usr/bin/kpcn" completions fish >"$stage/usr/share/fish/vendor_completions.d/kpcn.fish"
install -m 644 README.md "$stage/usr/share/doc/kpcn/README.md"
gzip -9n <CHANGELOG.md >"$stage/usr/share/doc/kpcn/changelog.gz"
chmod -R u+rwX,go+rX,go-w "$stage"

# Depends: the package of every shared library the files name (NEEDED; not what those
# load in turn), with the version installed here as the least (what they were built
# against).
depends=$(
    for f in "$stage/usr/bin/kpcn" "$lib/libkpcn.so.$version" "$lib/kpcn/oiio-plugins/kpcn.imageio.so"; do
        needed=$(objdump -p "$f" | awk '$1 == "NEEDED" { print $2 }')
        LD_LIBRARY_PATH=$lib ldd "$f" | awk -v needed="$needed" '
            BEGIN { n = split(needed, l, "\n"); for (i = 1; i <= n; i++) want[l[i]] = 1 }
            ($1 in want) && $3 ~ /^\// { print $3 }'
    done | sort -u | while read -r so; do
        real=$(readlink -f "$so")
        dpkg -S "$real" 2>/dev/null || dpkg -S "$so" 2>/dev/null || true
    done | cut -d: -f1 | sort -u | grep -vx "kpcn" | while read -r p; do
        echo "$p (>= $(dpkg-query -W -f='${Version}' "$p" | sed 's/^[0-9]*://; s/[-+~].*//'))"
    done | paste -sd, - | sed 's/,/, /g'
)
size=$(du -sk --exclude=DEBIAN "$stage" | cut -f1)
cat > "$stage/DEBIAN/control" <<CONTROL
Package: kpcn
Version: $version
Architecture: $arch
Maintainer: kpcn developers <kpcn@localhost>
Installed-Size: $size
Depends: $depends
Section: graphics
Priority: optional
Homepage: https://github.com/kpcn/kpcn
Description: Kernel-predicting Monte Carlo render denoiser
 kpcn removes Monte Carlo noise from rendered frames with kernel-predicting
 convolutional networks (Bako et al. 2017). It reads and writes layered EXRs
 through OpenImageIO and keeps every channel of its input. This package holds
 the kpcn command, the C library (libkpcn.so.$abi, libkpcn.a, kpcn.h, kpcn.pc),
 the OpenImageIO plugin and the Blender add-on.
CONTROL
# The shared library is new to the linker's cache.
echo "activate-noawait ldconfig" >"$stage/DEBIAN/triggers"

deb=$target/debian/kpcn_${version}_${arch}.deb
dpkg-deb --root-owner-group -Zxz --build "$stage" "$deb" >/dev/null
echo "$deb"
