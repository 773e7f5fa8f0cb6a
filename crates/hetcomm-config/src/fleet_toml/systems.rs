//! `[systems]`: each system's id and, in the long form, its module list and keys.

use super::*;
use crate::assemble::SysKeys;

impl P<'_> {
    pub(super) fn systems(&mut self, item: &Item, top: &Loc) -> Vec<SysSpec> {
        let loc = self.vloc(item, top);
        let Some(t) = self.table(item, "systems", &loc) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (name, v) in t.iter() {
            let nloc = self.kloc(t, name, &loc);
            let vl = self.vloc(v, &nloc);
            let path = format!("systems.{}", key_part(name));
            let (id, modules, keys) = if v.is_integer() || !v.is_table_like() {
                if !v.is_integer() {
                    self.wrong_type(
                        &vl,
                        &path,
                        "an id or a table `{ id = …, modules = […] }`",
                        v,
                        "write `Name = 0` or `Name = { id = 0, modules = [\"Plan\"] }`",
                    );
                    self.unusable_systems.push(name.to_string());
                    continue;
                }
                (
                    self.id16(v, &path, &vl, "system")
                        .map(|id| (id, vl.clone())),
                    None,
                    SysKeys::default(),
                )
            } else {
                let Some(st) = v.as_table_like() else {
                    self.unusable_systems.push(name.to_string());
                    continue;
                };
                self.unknown_keys(st, &SYSTEM_KEYS, Some(&path), &vl);
                let id = match st.get("id") {
                    Some(i) => {
                        let il = self.vloc(i, &vl);
                        self.id16(i, &format!("{path}.id"), &il, "system")
                            .map(|id| (id, il))
                    }
                    None => {
                        self.diag.err_help(
                            &vl,
                            format!("system `{name}` has no `id`"),
                            "add `id = <number>`",
                        );
                        None
                    }
                };
                let modules = st.get("modules").and_then(|m| {
                    let ml = self.vloc(m, &vl);
                    self.name_list(m, &format!("{path}.modules"), &ml)
                });
                let keys = self.system_keys(st, &path, &vl, name);
                (id, modules, keys)
            };
            match id {
                Some((id, id_loc)) => out.push(SysSpec {
                    id,
                    id_loc,
                    name: name.to_string(),
                    name_loc: nloc,
                    modules,
                    keys,
                }),
                // Already reported (its id): references to it should not be reported again.
                None => self.unusable_systems.push(name.to_string()),
            }
        }
        out
    }

    /// An array of strings with their locations.
    pub(super) fn name_list(
        &mut self,
        item: &Item,
        path: &str,
        loc: &Loc,
    ) -> Option<Vec<(String, Loc)>> {
        let Some(arr) = item.as_array() else {
            self.wrong_type(
                loc,
                path,
                "an array of module names",
                item,
                "e.g. `modules = [\"Plan\", \"Act\"]`",
            );
            return None;
        };
        let mut out = Vec::new();
        for v in arr.iter() {
            let vl = self.at(v.span(), loc);
            match v.as_str() {
                Some(s) => out.push((crate::names::nfc(s).into_owned(), vl)),
                None => {
                    let found = format!(
                        "{} `{}`",
                        type_name(&Item::Value(v.clone())),
                        v.span().and_then(|r| self.text.get(r)).unwrap_or("").trim()
                    );
                    self.diag.err_help(
                        &vl,
                        format!("`{path}` must list names in quotes, found {found}"),
                        "e.g. `modules = [\"Plan\", \"Act\"]`",
                    );
                }
            }
        }
        Some(out)
    }
}
