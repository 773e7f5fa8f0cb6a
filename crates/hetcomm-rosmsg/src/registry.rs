//! Where a bridge finds message definitions: a [`Registry`] of `.msg` files by `pkg/Type`,
//! from directories (a bridge's `msg_paths`, then an installed ROS: `ROS_PACKAGE_PATH` for
//! ROS 1, `AMENT_PREFIX_PATH` for ROS 2) and from the definitions shipped with hetcomm
//! (std_msgs, geometry_msgs, sensor_msgs, nav_msgs, diagnostic_msgs, tf2_msgs; and
//! builtin_interfaces for ROS 2: the upstream `.msg` files, in this crate's `msg/`). The first
//! place that has a type wins.
//!
//! A directory is searched for `PKG/msg/*.msg` at any depth up to a few levels (a catkin or
//! colcon workspace's `src`, an install prefix's `share`, a package itself). Files are read
//! when a type is first resolved ([`Registry::resolve`]): the result is a schema
//! ([`RosType`]) with its nested types, ROS 1's MD5 sum and full definition. Schemas are kept
//! for the life of the process, one per distinct definition.

use parking_lot::Mutex;
use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

use crate::idlfile;
use crate::msgfile::{self, Array, Base, MsgFile, Prim};
use crate::schema::{Flavour, RosType, Ty};
use crate::typehash;

mod shipped {
    include!(concat!(env!("OUT_DIR"), "/shipped.rs"));
}

/// How deep under a directory `PKG/msg` is looked for.
const MAX_DEPTH: usize = 5;

#[derive(Clone, Debug)]
enum Source {
    File(PathBuf),
    Shipped(&'static str),
}

/// Message definitions by `pkg/Type`, for one flavour of ROS.
#[derive(Debug)]
pub struct Registry {
    flavour: Flavour,
    index: HashMap<String, Source>,
    /// Where it looked, in order, for "not found".
    searched: Vec<String>,
    shipped_packages: Vec<String>,
    resolved: Mutex<HashMap<String, &'static RosType>>,
}

/// Every schema made so far, by flavour and full definition: one per distinct definition.
static INTERNED: Mutex<Vec<&'static RosType>> = Mutex::new(Vec::new());

/// The environment variable that lists an installed ROS's packages, and how.
fn ros_env(flavour: Flavour) -> &'static str {
    match flavour {
        Flavour::Ros1 => "ROS_PACKAGE_PATH",
        Flavour::Ros2 => "AMENT_PREFIX_PATH",
    }
}

fn leak(s: String) -> &'static str {
    Box::leak(s.into_boxed_str())
}

impl Registry {
    fn empty(flavour: Flavour) -> Registry {
        Registry {
            flavour,
            index: HashMap::new(),
            searched: Vec::new(),
            shipped_packages: Vec::new(),
            resolved: Mutex::default(),
        }
    }

    /// The shipped definitions only.
    pub fn shipped(flavour: Flavour) -> Registry {
        let mut r = Registry::empty(flavour);
        r.add_shipped();
        r
    }

    /// `dirs` (in order), then the shipped definitions: no installed ROS. A directory that
    /// does not exist is an error naming it.
    pub fn from_dirs(flavour: Flavour, dirs: &[PathBuf]) -> Result<Registry, String> {
        let mut r = Registry::with_dirs(flavour, dirs, "")?;
        r.add_shipped();
        Ok(r)
    }

    fn with_dirs(flavour: Flavour, dirs: &[PathBuf], label: &str) -> Result<Registry, String> {
        let mut r = Registry::empty(flavour);
        for d in dirs {
            if !d.is_dir() {
                return Err(format!("`{}` is not a directory", d.display()));
            }
            r.add_dir(d, &format!("{label}{}", d.display()));
        }
        Ok(r)
    }

    /// What a bridge reads: `msg_paths` (in order), then the installed ROS's packages
    /// (`ROS_PACKAGE_PATH` for ROS 1, `AMENT_PREFIX_PATH`'s `share` directories for ROS 2,
    /// where set), then the shipped definitions.
    pub fn for_bridge(flavour: Flavour, msg_paths: &[PathBuf]) -> Result<Registry, String> {
        let mut r = Registry::with_dirs(flavour, msg_paths, "msg_paths entry ")?;
        let var = ros_env(flavour);
        if let Some(value) = std::env::var_os(var) {
            for entry in std::env::split_paths(&value) {
                let dir = match flavour {
                    Flavour::Ros1 => entry.clone(),
                    Flavour::Ros2 => entry.join("share"),
                };
                if dir.is_dir() {
                    r.add_dir(&dir, &format!("{var} entry {}", entry.display()));
                }
            }
        }
        r.add_shipped();
        Ok(r)
    }

    fn add_dir(&mut self, root: &Path, label: &str) {
        let before = self.index.len();
        self.scan(root, 0);
        self.searched
            .push(format!("{label} ({} types)", self.index.len() - before));
    }

    fn scan(&mut self, dir: &Path, depth: usize) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        let mut subdirs: Vec<PathBuf> = entries
            .filter_map(Result::ok)
            .filter(|e| e.file_type().is_ok_and(|t| t.is_dir() || t.is_symlink()))
            .map(|e| e.path())
            .filter(|p| p.is_dir())
            .collect();
        subdirs.sort();
        let package = dir
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_default();
        for sub in subdirs {
            let name = sub.file_name().unwrap_or_default().to_string_lossy();
            if name.starts_with('.') {
                continue;
            }
            if name == "msg" && msgfile::valid_package(&package) {
                self.add_msg_dir(&package, &sub);
            } else if depth < MAX_DEPTH {
                self.scan(&sub, depth + 1);
            }
        }
    }

    fn add_msg_dir(&mut self, package: &str, dir: &Path) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        // A ROS 2 package may ship a type as `.idl` only; where both are there, the `.msg`.
        let mut found: Vec<(bool, String, PathBuf)> = Vec::new();
        for e in entries.filter_map(Result::ok) {
            let path = e.path();
            let idl = match path.extension().and_then(|x| x.to_str()) {
                Some("msg") => false,
                Some("idl") if self.flavour == Flavour::Ros2 => true,
                _ => continue,
            };
            let stem = path.file_stem().unwrap_or_default().to_string_lossy();
            found.push((idl, format!("{package}/{stem}"), path));
        }
        found.sort();
        for (_, name, path) in found {
            self.index.entry(name).or_insert(Source::File(path));
        }
    }

    fn add_shipped(&mut self) {
        let list = match self.flavour {
            Flavour::Ros1 => shipped::ROS1,
            Flavour::Ros2 => shipped::ROS2,
        };
        let mut packages = BTreeSet::new();
        for (pkg, name, text) in list {
            packages.insert(pkg.to_string());
            self.index
                .entry(format!("{pkg}/{name}"))
                .or_insert(Source::Shipped(text));
        }
        self.shipped_packages = packages.into_iter().collect();
        self.searched.push(format!(
            "the definitions shipped with hetcomm ({})",
            self.shipped_packages.join(", ")
        ));
    }

    /// The packages of the shipped definitions.
    pub fn packages(&self) -> &[String] {
        &self.shipped_packages
    }

    /// The flavour of ROS it reads definitions for.
    pub fn flavour(&self) -> Flavour {
        self.flavour
    }

    /// Where it looks, in order (for "not found" messages).
    pub fn searched(&self) -> String {
        self.searched.join("; ")
    }

    /// Every type it can name, resolved (sorted by name); the first that does not resolve is
    /// the error.
    pub fn resolve_all(&self) -> Result<Vec<&'static RosType>, String> {
        self.names().iter().map(|n| self.resolve(n)).collect()
    }

    /// Every type it can name, sorted.
    pub fn names(&self) -> Vec<String> {
        let mut v: Vec<String> = self.index.keys().cloned().collect();
        v.sort();
        v
    }

    /// The schema of `name` (`pkg/Type`, or `pkg/msg/Type`) with every type it uses. The
    /// error says why: a type (it or one it uses) not found, and where it looked; a
    /// malformed file at `file:line`; a type that contains itself.
    pub fn resolve(&self, name: &str) -> Result<&'static RosType, String> {
        let full = match name.split('/').collect::<Vec<_>>()[..] {
            [pkg, "msg", ty] => format!("{pkg}/{ty}"),
            [pkg, ty] => format!("{pkg}/{ty}"),
            _ => return Err(format!("`{name}` is not a ROS type name: write `pkg/Type`")),
        };
        self.resolve_full(&full, &mut Vec::new(), "")
    }

    fn load(&self, full: &str, used_at: &str) -> Result<MsgFile, String> {
        let (pkg, ty) = full.split_once('/').unwrap_or(("", full));
        let source = self.index.get(full).ok_or_else(|| {
            format!(
                "the ROS type `{full}`{used_at} was not found: looked in {}",
                self.searched()
            )
        })?;
        let (text, file) = match source {
            Source::File(path) => {
                let text = std::fs::read_to_string(path)
                    .map_err(|e| format!("reading {}: {e}", path.display()))?;
                (text, path.display().to_string())
            }
            Source::Shipped(text) => {
                let dir = match self.flavour {
                    Flavour::Ros1 => "ros1",
                    Flavour::Ros2 => "ros2",
                };
                (
                    text.to_string(),
                    format!("(shipped) {dir}/{pkg}/msg/{ty}.msg"),
                )
            }
        };
        if file.ends_with(".idl") {
            return idlfile::parse(&text, &file, pkg, ty).map_err(|e| e.to_string());
        }
        msgfile::parse(&text, &file, pkg, ty, self.flavour).map_err(|e| e.to_string())
    }

    fn resolve_full(
        &self,
        full: &str,
        chain: &mut Vec<String>,
        used_at: &str,
    ) -> Result<&'static RosType, String> {
        if let Some(t) = self.lock().get(full) {
            return Ok(t);
        }
        if chain.iter().any(|c| c == full) {
            return Err(format!(
                "`{full}` contains itself (through {}): a message cannot",
                chain.join(" → ")
            ));
        }
        let file = self.load(full, used_at)?;
        chain.push(full.to_string());
        let mut fields = Vec::with_capacity(file.fields.len());
        let mut md5_lines: Vec<String> = file
            .constants
            .iter()
            .map(|c| format!("{} {}={}", c.ty, c.name, c.value))
            .collect();
        let mut deps: Vec<&'static RosType> = Vec::new();
        for f in &file.fields {
            let at = format!(" (field `{}` of {full}, {}:{})", f.name, file.file, f.line);
            let elem = match &f.ty.base {
                Base::Prim(p) => prim(*p),
                Base::Str(None) => Ty::Str,
                Base::Str(Some(n)) => Ty::BoundedStr(*n),
                Base::WStr(_) => {
                    return Err(format!(
                        "{}:{}: field `{}` is a wstring, which the bridges do not convert",
                        file.file, f.line, f.name
                    ))
                }
                Base::Time => Ty::Msg(&ros1::TIME),
                Base::Duration => Ty::Msg(&ros1::DURATION),
                Base::Msg(sub) => {
                    let t = self.resolve_full(sub, chain, &at)?;
                    deps.push(t);
                    Ty::Msg(t)
                }
            };
            md5_lines.push(match (&f.ty.base, &elem) {
                (Base::Msg(_), Ty::Msg(t)) => format!("{} {}", t.md5, f.name),
                _ => format!("{} {}", f.ty.text, f.name),
            });
            let ty = match f.ty.array {
                Array::No => elem,
                Array::Fixed(n) => Ty::Array(Box::leak(Box::new(elem)), n),
                Array::Bounded(n) => Ty::Seq(Box::leak(Box::new(elem)), Some(n)),
                Array::Unbounded => Ty::Seq(Box::leak(Box::new(elem)), None),
            };
            fields.push((f.name.clone(), ty));
        }
        chain.pop();
        let definition = full_definition(&file.text, &deps);
        let (md5, identity) = match self.flavour {
            Flavour::Ros1 => (
                format!("{:x}", md5::compute(md5_lines.join("\n"))),
                Identity::default(),
            ),
            Flavour::Ros2 => {
                let description = typehash::description(full, &file.fields);
                let hash = typehash::type_hash(&description, &deps);
                (String::new(), Identity { hash, description })
            }
        };
        let t = intern(full, fields, &file, md5, definition, identity);
        self.lock().insert(full.to_string(), t);
        Ok(t)
    }

    fn lock(&self) -> parking_lot::MutexGuard<'_, HashMap<String, &'static RosType>> {
        self.resolved.lock()
    }
}

fn prim(p: Prim) -> Ty {
    match p {
        Prim::Bool => Ty::Bool,
        Prim::I8 => Ty::I8,
        Prim::U8 => Ty::U8,
        Prim::I16 => Ty::I16,
        Prim::U16 => Ty::U16,
        Prim::I32 => Ty::I32,
        Prim::U32 => Ty::U32,
        Prim::I64 => Ty::I64,
        Prim::U64 => Ty::U64,
        Prim::F32 => Ty::F32,
        Prim::F64 => Ty::F64,
    }
}

/// The own text of each type `deps` names, recursively, first use first (genmsg's order).
fn full_definition(text: &str, deps: &[&'static RosType]) -> String {
    fn collect(t: &'static RosType, out: &mut Vec<&'static RosType>) {
        if !out.iter().any(|o| o.name == t.name) {
            out.push(t);
        }
        for (_, ty) in t.fields {
            let mut ty = ty;
            while let Ty::Array(e, _) | Ty::Seq(e, _) = ty {
                ty = e;
            }
            if let Ty::Msg(m) = ty {
                if !m.md5.is_empty() || !m.definition.is_empty() {
                    collect(m, out);
                }
            }
        }
    }
    let mut all = Vec::new();
    for d in deps {
        collect(d, &mut all);
    }
    let mut out = text.trim_end_matches('\n').to_string();
    out.push('\n');
    for d in all {
        out.push_str(&"=".repeat(80));
        out.push('\n');
        out.push_str(&format!("MSG: {}\n", d.name));
        out.push_str(own_text(d));
        out.push('\n');
    }
    out.pop();
    out
}

/// A type's own text: its full definition up to the first type it uses.
fn own_text(t: &RosType) -> &str {
    let sep = format!("\n{}\nMSG: ", "=".repeat(80));
    match t.definition.find(&sep) {
        Some(i) => &t.definition[..i],
        None => t.definition,
    }
}

/// What identifies a ROS 2 type besides its name: its type hash and the description hashed.
#[derive(Default)]
struct Identity {
    hash: String,
    description: String,
}

fn intern(
    full: &str,
    fields: Vec<(String, Ty)>,
    file: &MsgFile,
    md5: String,
    definition: String,
    identity: Identity,
) -> &'static RosType {
    let mut all = INTERNED.lock();
    if let Some(t) = all.iter().find(|t| {
        t.name == full && t.definition == definition && t.md5 == md5 && t.type_hash == identity.hash
    }) {
        return t;
    }
    let fields: Vec<(&'static str, Ty)> = fields.into_iter().map(|(n, t)| (leak(n), t)).collect();
    let constants: Vec<(&'static str, &'static str, &'static str)> = file
        .constants
        .iter()
        .map(|c| {
            (
                leak(c.ty.clone()),
                leak(c.name.clone()),
                leak(c.value.clone()),
            )
        })
        .collect();
    let t: &'static RosType = Box::leak(Box::new(RosType {
        name: leak(full.to_string()),
        fields: Box::leak(fields.into_boxed_slice()),
        constants: Box::leak(constants.into_boxed_slice()),
        md5: leak(md5),
        definition: leak(definition),
        type_hash: leak(identity.hash),
        description: leak(identity.description),
    }));
    all.push(t);
    t
}

/// Every shipped type of both flavours (for tests and fuzzing).
pub fn every_shipped_type() -> Result<Vec<(Flavour, &'static RosType)>, String> {
    let mut out = Vec::new();
    for f in [Flavour::Ros1, Flavour::Ros2] {
        out.extend(f.shipped().resolve_all()?.into_iter().map(|t| (f, t)));
    }
    Ok(out)
}

/// ROS 1's builtin `time` and `duration`.
pub mod ros1 {
    use crate::schema::{RosType, Ty};

    /// `time`: `uint32 secs`, `uint32 nsecs`.
    pub static TIME: RosType = RosType {
        name: "time",
        fields: &[("secs", Ty::U32), ("nsecs", Ty::U32)],
        constants: &[],
        md5: "",
        definition: "",
        type_hash: "",
        description: "",
    };

    /// `duration`: `int32 secs`, `int32 nsecs`.
    pub static DURATION: RosType = RosType {
        name: "duration",
        fields: &[("secs", Ty::I32), ("nsecs", Ty::I32)],
        constants: &[],
        md5: "",
        definition: "",
        type_hash: "",
        description: "",
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, rel: &str, text: &str) {
        let p = dir.join(rel);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, text).unwrap();
    }

    fn temp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!(
            "hetcomm-rosmsg-{tag}-{}-{}",
            std::process::id(),
            rand::random::<u32>()
        ));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn every_shipped_type_resolves_in_both_flavours() {
        for f in [Flavour::Ros1, Flavour::Ros2] {
            let r = Flavour::shipped(f);
            let names = r.names();
            assert!(names.len() > 100, "{f:?}: {}", names.len());
            for n in names {
                r.resolve(&n).unwrap_or_else(|e| panic!("{f:?} {n}: {e}"));
            }
        }
    }

    #[test]
    fn the_md5_of_header_and_its_full_definition_are_ros_1_s() {
        let r = Flavour::shipped(Flavour::Ros1);
        let h = r.resolve("std_msgs/Header").unwrap();
        assert_eq!(h.md5, "2176decaecbce78abc3b96ef049fabed");
        let ps = r.resolve("geometry_msgs/PoseStamped").unwrap();
        assert_eq!(ps.md5, "d3812c3cbc69362b77dc0b19b345f8f5");
        let deps: Vec<&str> = ps
            .definition
            .lines()
            .filter_map(|l| l.strip_prefix("MSG: "))
            .collect();
        assert_eq!(
            deps,
            [
                "std_msgs/Header",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion"
            ]
        );
        assert!(!ps.definition.ends_with('\n'));
    }

    #[test]
    fn every_shipped_ros_1_md5_sum_is_what_rosmsg_prints() {
        let table = include_str!("../msg/ros1-md5sums.txt");
        let r = Flavour::shipped(Flavour::Ros1);
        let mut checked = 0;
        for line in table.lines().filter(|l| !l.starts_with('#')) {
            let (name, md5) = line.split_once(' ').unwrap();
            assert_eq!(r.resolve(name).unwrap().md5, md5, "{name}");
            checked += 1;
        }
        assert_eq!(
            checked,
            r.names().len(),
            "every shipped type is in the table"
        );
    }

    #[test]
    fn custom_packages_nested_types_and_where_it_looked() {
        let d = temp("custom");
        write(
            &d,
            "src/my_robot_msgs/msg/Status.msg",
            "uint8 OK=0\nuint8 ERROR=2\nHeader header\nuint8 level\nPart[] parts\n\
             geometry_msgs/Pose[2] poses\n",
        );
        write(
            &d,
            "src/my_robot_msgs/msg/Part.msg",
            "string name\nfloat32[3] temps\n",
        );
        let r = Registry::from_dirs(Flavour::Ros1, std::slice::from_ref(&d)).unwrap();
        let s = r.resolve("my_robot_msgs/Status").unwrap();
        assert_eq!(s.constants.len(), 2);
        assert!(
            matches!(s.fields[2].1, Ty::Seq(Ty::Msg(p), None) if p.name == "my_robot_msgs/Part")
        );
        assert!(
            matches!(s.fields[3].1, Ty::Array(Ty::Msg(p), 2) if p.name == "geometry_msgs/Pose")
        );
        let e = r.resolve("my_robot_msgs/Missing").unwrap_err();
        assert!(
            e.starts_with("the ROS type `my_robot_msgs/Missing` was not found: looked in "),
            "{e}"
        );
        assert!(e.contains(&format!("{} (2 types)", d.display())), "{e}");
        assert!(
            e.contains("the definitions shipped with hetcomm (actionlib_msgs, diagnostic_msgs, "),
            "{e}"
        );
        write(
            &d,
            "src/my_robot_msgs/msg/Broken.msg",
            "int32 a\nUnknown b\n",
        );
        let r = Registry::from_dirs(Flavour::Ros1, std::slice::from_ref(&d)).unwrap();
        let e = r.resolve("my_robot_msgs/Broken").unwrap_err();
        assert!(
            e.starts_with(
                "the ROS type `my_robot_msgs/Unknown` (field `b` of my_robot_msgs/Broken, "
            ),
            "{e}"
        );
        assert!(e.contains("Broken.msg:2) was not found"), "{e}");
        write(&d, "src/my_robot_msgs/msg/Bad.msg", "int32 a\nint32[x] b\n");
        let r = Registry::from_dirs(Flavour::Ros1, std::slice::from_ref(&d)).unwrap();
        let e = r.resolve("my_robot_msgs/Bad").unwrap_err();
        assert!(
            e.ends_with("Bad.msg:2: `int32[x]`: `x` is not an array size (a whole number from 1)"),
            "{e}"
        );
        write(
            &d,
            "src/my_robot_msgs/msg/Loop.msg",
            "my_robot_msgs/Loop2 a\n",
        );
        write(&d, "src/my_robot_msgs/msg/Loop2.msg", "Loop b\n");
        let r = Registry::from_dirs(Flavour::Ros1, std::slice::from_ref(&d)).unwrap();
        let e = r.resolve("my_robot_msgs/Loop").unwrap_err();
        assert!(e.contains("`my_robot_msgs/Loop` contains itself"), "{e}");
        assert!(Registry::from_dirs(Flavour::Ros1, &[d.join("nope")]).is_err());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_directory_overrides_the_shipped_definitions() {
        let d = temp("override");
        write(&d, "std_msgs/msg/String.msg", "string data\nuint8 extra\n");
        let r = Registry::from_dirs(Flavour::Ros2, std::slice::from_ref(&d)).unwrap();
        assert_eq!(r.resolve("std_msgs/msg/String").unwrap().fields.len(), 2);
        assert_eq!(
            Flavour::Ros2
                .lookup("std_msgs/String")
                .unwrap()
                .fields
                .len(),
            1
        );
        std::fs::remove_dir_all(&d).unwrap();
    }
}
