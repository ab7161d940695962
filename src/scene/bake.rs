//! The bake cache: precomputed data of a scene kept on disk between runs,
//! one file per scene and kind of data, so a server starts from what an
//! earlier one computed.
//!
//! A file is named by the scene file's content hash ([`Scene::source_hash`]),
//! the kind (`occluders`) and a hash of the parameters it was built with, so
//! a changed scene or setting never finds a stale file. Its header holds a
//! magic, the format version, the kind, the parameters, the scene hash,
//! the payload's length and an xxh3 checksum of the payload; a file whose
//! header, length or checksum disagrees is rebuilt, with the reason logged,
//! never trusted. Files are written to a temporary name in the same folder
//! and renamed into place, so a killed bake leaves nothing that loads, and
//! two processes baking at once both end with a whole file. The format is
//! in `proto/bake-format.md`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use xxhash_rust::xxh3::{xxh3_64, xxh3_128};

use super::Scene;

/// The first bytes of every bake file.
pub const MAGIC: &[u8; 8] = b"PVSDBAKE";

/// The format of the header; a file of another version is rebuilt.
pub const FORMAT_VERSION: u32 = 1;

/// Where bakes are kept.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BakeCache {
    dir: PathBuf,
}

/// How [`BakeCache::load_or_build`] got its data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Baked {
    /// Read from the file.
    Loaded,
    /// Computed, and written for next time (or not, with why).
    Built {
        /// Why no usable file was there (`none yet`, a checksum mismatch…).
        reason: String,
        /// Why the new file could not be written, if it could not.
        unsaved: Option<String>,
    },
}

impl BakeCache {
    /// A cache in `dir` (made when first written).
    pub fn new(dir: impl Into<PathBuf>) -> BakeCache {
        BakeCache { dir: dir.into() }
    }

    /// Whether bakes can be written here: the folder is made if missing and
    /// a probe file written and removed. `Err` says why not (a read-only
    /// or full disk, a path through a file); bakes are then built in
    /// memory each time, and the caller should say so once.
    pub fn check_writable(&self) -> Result<(), String> {
        std::fs::create_dir_all(&self.dir)
            .map_err(|e| format!("cannot make {}: {e}", self.dir.display()))?;
        let probe = self
            .dir
            .join(format!(".pvsd-write-probe.{}", std::process::id()));
        let written = std::fs::File::create(&probe)
            .and_then(|mut f| f.write_all(b"pvsd").and_then(|()| f.sync_all()));
        let _ = std::fs::remove_file(&probe);
        written.map_err(|e| format!("cannot write in {}: {e}", self.dir.display()))
    }

    /// The user's cache folder for pvsd: `$XDG_CACHE_HOME/pvsd`, else
    /// `$HOME/.cache/pvsd`; `None` when neither is set.
    pub fn default_dir() -> Option<PathBuf> {
        let xdg = std::env::var_os("XDG_CACHE_HOME").filter(|v| !v.is_empty());
        let base = xdg
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))?;
        Some(base.join("pvsd"))
    }

    /// The file of `kind` with `params` for the scene with `scene_hash`.
    pub fn path(&self, scene_hash: u128, kind: &str, params: &str) -> PathBuf {
        let p = xxh3_64(params.as_bytes());
        self.dir
            .join(format!("{scene_hash:032x}-{kind}-{p:016x}.bake"))
    }

    /// The payload of `kind` with `params` for `scene`: read from its file
    /// when one is there and whole, else made by `build` and written for
    /// next time. `decode` turns a payload into the data (an `Err` rebuilds,
    /// like a bad checksum); `encode` the data into a payload. A scene
    /// built in memory (no source hash) is built every time.
    pub fn load_or_build<T>(
        &self,
        scene: &Scene,
        kind: &str,
        params: &str,
        build: impl FnOnce() -> T,
        encode: impl FnOnce(&T) -> Vec<u8>,
        decode: impl FnOnce(&[u8]) -> Result<T, String>,
    ) -> (T, Baked) {
        let Some(hash) = scene.source_hash() else {
            let reason = "the scene was not loaded from a file".to_string();
            return (
                build(),
                Baked::Built {
                    reason,
                    unsaved: None,
                },
            );
        };
        let path = self.path(hash, kind, params);
        let started = Instant::now();
        let reason = match read(&path, hash, kind, params).and_then(|p| decode(&p)) {
            Ok(data) => {
                tracing::info!(scene = %scene.id, kind, path = %path.display(), ms = started.elapsed().as_millis() as u64, "loaded a bake");
                return (data, Baked::Loaded);
            }
            Err(reason) => reason,
        };
        let started = Instant::now();
        let data = build();
        let built_ms = started.elapsed().as_millis() as u64;
        let unsaved = write(&path, hash, kind, params, &encode(&data)).err();
        tracing::info!(
            scene = %scene.id, kind, path = %path.display(), built_ms, %reason,
            unsaved = unsaved.as_deref().unwrap_or("no"),
            "baked"
        );
        (data, Baked::Built { reason, unsaved })
    }
}

/// The header: everything before the payload.
fn header(scene_hash: u128, kind: &str, params: &str, payload: &[u8]) -> Vec<u8> {
    let mut h = Vec::new();
    h.extend_from_slice(MAGIC);
    h.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    for text in [kind, params] {
        h.extend_from_slice(&(text.len() as u32).to_le_bytes());
        h.extend_from_slice(text.as_bytes());
    }
    h.extend_from_slice(&scene_hash.to_le_bytes());
    h.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    h.extend_from_slice(&xxh3_64(payload).to_le_bytes());
    h
}

/// A whole file's payload, or why the file cannot be used.
fn read(path: &Path, scene_hash: u128, kind: &str, params: &str) -> Result<Vec<u8>, String> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Err("none yet".into()),
        Err(e) => return Err(format!("cannot read {}: {e}", path.display())),
    };
    let mut at = 0usize;
    let mut take = |n: usize| -> Result<&[u8], String> {
        let part = bytes
            .get(at..at + n)
            .ok_or_else(|| "the file is truncated".to_string())?;
        at += n;
        Ok(part)
    };
    if take(8)? != MAGIC {
        return Err("not a bake file (bad magic)".into());
    }
    let version = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes"));
    if version != FORMAT_VERSION {
        return Err(format!("format version {version}, not {FORMAT_VERSION}"));
    }
    for (what, expected) in [("kind", kind), ("parameters", params)] {
        let len = u32::from_le_bytes(take(4)?.try_into().expect("4 bytes")) as usize;
        if take(len)? != expected.as_bytes() {
            return Err(format!("made for other {what}"));
        }
    }
    let hash = u128::from_le_bytes(take(16)?.try_into().expect("16 bytes"));
    if hash != scene_hash {
        return Err("made for another scene".into());
    }
    let len = u64::from_le_bytes(take(8)?.try_into().expect("8 bytes"));
    let sum = u64::from_le_bytes(take(8)?.try_into().expect("8 bytes"));
    let payload = &bytes[at..];
    if payload.len() as u64 != len {
        return Err(format!(
            "the payload is {} bytes, the header says {len}: truncated or grown",
            payload.len()
        ));
    }
    if xxh3_64(payload) != sum {
        return Err("the payload's checksum does not match: corrupt".into());
    }
    Ok(payload.to_vec())
}

/// Writes a whole file under a temporary name, then renames it into place.
fn write(
    path: &Path,
    scene_hash: u128,
    kind: &str,
    params: &str,
    payload: &[u8],
) -> Result<(), String> {
    let dir = path.parent().expect("a bake path has a folder");
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot make {}: {e}", dir.display()))?;
    let nonce = xxh3_128(
        format!(
            "{:?}{:?}",
            std::time::SystemTime::now(),
            std::thread::current().id()
        )
        .as_bytes(),
    );
    let tmp = dir.join(format!(
        ".{}.{}.{nonce:x}.tmp",
        path.file_name().expect("a file name").to_string_lossy(),
        std::process::id()
    ));
    let written = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(&header(scene_hash, kind, params, payload))?;
        f.write_all(payload)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    written.map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        format!("cannot write {}: {e}", path.display())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::generate::{CityOptions, city};
    use crate::scene::load_slice;

    fn scene(seed: u64) -> Scene {
        let doc = city(&CityOptions {
            buildings: 20,
            seed,
            ..CityOptions::default()
        });
        load_slice("city", &doc.to_glb(), None, Path::new("city.glb")).unwrap()
    }

    fn bake(cache: &BakeCache, s: &Scene, payload: &[u8]) -> (Vec<u8>, Baked) {
        cache.load_or_build(
            s,
            "test",
            "p=1",
            || payload.to_vec(),
            |d| d.clone(),
            |b| Ok(b.to_vec()),
        )
    }

    #[test]
    fn a_bake_is_reused_and_a_damaged_one_rebuilt() {
        let dir = tempfile::tempdir().unwrap();
        let cache = BakeCache::new(dir.path().join("bakes"));
        let s = scene(1);
        let (data, how) = bake(&cache, &s, b"payload one");
        assert_eq!(data, b"payload one");
        assert!(
            matches!(how, Baked::Built { ref reason, unsaved: None } if reason == "none yet"),
            "{how:?}"
        );
        // Loaded the second time, whatever build would make now.
        let (data, how) = bake(&cache, &s, b"other");
        assert_eq!((data.as_slice(), how), (&b"payload one"[..], Baked::Loaded));

        let path = cache.path(s.source_hash().unwrap(), "test", "p=1");
        let whole = std::fs::read(&path).unwrap();
        let cases: [(&str, Vec<u8>); 4] = [
            ("checksum", {
                let mut b = whole.clone();
                *b.last_mut().unwrap() ^= 1;
                b
            }),
            ("truncated", whole[..whole.len() - 3].to_vec()),
            ("truncated", whole[..10].to_vec()),
            ("version", {
                let mut b = whole.clone();
                b[8] = 9;
                b
            }),
        ];
        for (why, bytes) in cases {
            std::fs::write(&path, bytes).unwrap();
            let (data, how) = bake(&cache, &s, b"rebuilt");
            assert_eq!(data, b"rebuilt", "{why}");
            match how {
                Baked::Built {
                    reason,
                    unsaved: None,
                } => assert!(reason.contains(why), "{why}: {reason}"),
                other => panic!("{why}: {other:?}"),
            }
            // And the rebuilt file is whole again.
            assert_eq!(bake(&cache, &s, b"x").1, Baked::Loaded);
        }
    }

    #[test]
    fn another_scene_or_setting_never_finds_the_file_and_leftovers_do_not_load() {
        let dir = tempfile::tempdir().unwrap();
        let cache = BakeCache::new(dir.path());
        let (a, b) = (scene(1), scene(2));
        assert_ne!(a.source_hash(), b.source_hash());
        bake(&cache, &a, b"a");
        assert!(matches!(bake(&cache, &b, b"b").1, Baked::Built { .. }));
        let other = cache.load_or_build(
            &a,
            "test",
            "p=2",
            || b"c".to_vec(),
            |d| d.clone(),
            |x| Ok(x.to_vec()),
        );
        assert!(matches!(other.1, Baked::Built { .. }));
        // A bake killed mid-write leaves only a temporary file, never
        // under the name that loads.
        let hash = a.source_hash().unwrap();
        std::fs::remove_file(cache.path(hash, "test", "p=1")).unwrap();
        let name = cache
            .path(hash, "test", "p=1")
            .file_name()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        std::fs::write(
            dir.path().join(format!(".{name}.123.abc.tmp")),
            b"PVSDBAKE half",
        )
        .unwrap();
        assert!(
            matches!(bake(&cache, &a, b"again").1, Baked::Built { ref reason, .. } if reason == "none yet")
        );
        // A scene built in memory has no file to name a bake by.
        let mut builder = crate::scene::SceneBuilder::new("mem");
        builder.begin_object("o", None);
        let mem = builder.finish();
        assert!(matches!(bake(&cache, &mem, b"m").1, Baked::Built { .. }));
    }

    #[test]
    fn two_bakers_at_once_both_end_with_a_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let cache = BakeCache::new(dir.path());
        let s = scene(3);
        std::thread::scope(|t| {
            for _ in 0..4 {
                t.spawn(|| bake(&cache, &s, &[7u8; 100_000]));
            }
        });
        let (data, how) = bake(&cache, &s, b"no");
        assert_eq!((data, how), (vec![7u8; 100_000], Baked::Loaded));
        let leftovers = std::fs::read_dir(dir.path()).unwrap().count();
        assert_eq!(leftovers, 1, "only the bake itself");
    }
}
