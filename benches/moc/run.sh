#!/bin/sh
# Intel's Masked Occlusion Culling on the views of `pvsd eval --walk views`
# (60 frames, 512×320), side by side with pvsd on this machine (issue 16).
#
#   benches/moc/run.sh SCENE MOC_SRC_DIR [harness options: --reps N --per-object --soup --verbose]
#
# 1. dumps the scene's views, opaque triangles, boxes and ground truth
#    (cargo run --release --example moc_dump; reused while newer than the
#    scene and the example's binary);
# 2. compiles MOC's sources from MOC_SRC_DIR (a checkout of
#    github.com/GameTechDev/MaskedOcclusionCulling) with benches/moc/harness.cpp:
#    g++ -O3 (-mavx2 -mfma for the AVX2 code), NDEBUG, no threads (rebuilt
#    when a source is newer);
# 3. runs the harness: MOC's AVX2 implementation, one thread.
#
# Builds run under `nice -n 19`; the timed run does not. Work files go to
# $MOC_WORK (default: $CARGO_TARGET_DIR or target/, then moc/).
set -eu

if [ $# -lt 2 ]; then
    echo "usage: $0 SCENE MOC_SRC_DIR [--reps N] [--per-object] [--soup] [--verbose]" >&2
    exit 2
fi
scene=$1
moc=$(cd "$2" && pwd)
shift 2
[ -f "$moc/MaskedOcclusionCulling.cpp" ] || { echo "$0: no MaskedOcclusionCulling.cpp in $moc" >&2; exit 2; }

here=$(cd "$(dirname "$0")" && pwd)
repo=$(cd "$here/../.." && pwd)
target=${CARGO_TARGET_DIR:-$repo/target}
work=${MOC_WORK:-$target/moc}
mkdir -p "$work"

# 1. The dump.
(cd "$repo" && nice -n 19 cargo build --quiet --release --example moc_dump)
name=$(basename "$scene")
dump=$work/${name%.*}.dump
if [ ! -f "$dump" ] || [ "$scene" -nt "$dump" ] || [ "$target/release/examples/moc_dump" -nt "$dump" ]; then
    (cd "$repo" && nice -n 19 cargo run --quiet --release --example moc_dump -- "$scene" "$dump")
fi

# 2. MOC and the harness, as MOC's CMakeLists.txt compiles it: its AVX2
# (and AVX-512 stub) files with -mavx2 -mfma -msse4.1; its dispatch file,
# which refuses to be compiled for more than the lowest target it
# supports, with -msse4.1. The harness (whose box tests are timed) gets
# the AVX2 flags. Only MOC's AVX2 implementation runs.
bin=$work/harness
stale=0
[ -x "$bin" ] || stale=1
for f in "$here/harness.cpp" "$here/gcc_compat.h" "$moc"/MaskedOcclusionCulling*.cpp "$moc"/MaskedOcclusionCulling*.h "$moc"/*.inl; do
    [ "$f" -nt "$bin" ] && stale=1
done
# A harness built from another MOC directory is rebuilt.
[ "$(cat "$bin.src" 2>/dev/null || true)" = "$moc" ] || stale=1
if [ "$stale" = 1 ]; then
    echo "building MOC from $moc" >&2
    cxx="nice -n 19 g++ -std=c++17 -O3 -DNDEBUG -include $here/gcc_compat.h -I$moc"
    avx2="-mavx2 -mfma -msse4.1"
    $cxx -msse4.1 -c "$moc/MaskedOcclusionCulling.cpp" -o "$work/moc.o"
    $cxx $avx2 -c "$moc/MaskedOcclusionCullingAVX2.cpp" -o "$work/moc_avx2.o"
    $cxx $avx2 -c "$moc/MaskedOcclusionCullingAVX512.cpp" -o "$work/moc_avx512.o"
    $cxx $avx2 -c "$here/harness.cpp" -o "$work/harness.o"
    nice -n 19 g++ -o "$bin" "$work/harness.o" "$work/moc.o" "$work/moc_avx2.o" "$work/moc_avx512.o"
    echo "$moc" > "$bin.src"
fi

# 3. The timed run.
echo "== $scene"
"$bin" "$dump" "$@"
