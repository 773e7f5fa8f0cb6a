//! `[modules]` and `[inbox]`: module ids and inbox policies.

use super::*;

impl P<'_> {
    pub(super) fn inbox_fields(
        &mut self,
        t: &dyn TableLike,
        path: &str,
        cap_key: &str,
        base: InboxDefaults,
        loc: &Loc,
    ) -> InboxDefaults {
        let mut out = base;
        if let Some(v) = t.get(cap_key) {
            let vl = self.vloc(v, loc);
            if let Some(c) = self.int_in(
                v,
                &format!("{path}.{cap_key}"),
                &vl,
                1,
                i64::MAX,
                "an inbox holds at least one message, e.g. 1024",
            ) {
                out.capacity = usize::try_from(c).unwrap_or(usize::MAX);
            }
        }
        if let Some(v) = t.get("overflow") {
            let vl = self.vloc(v, loc);
            if let Some(i) = self.choice(
                v,
                &format!("{path}.overflow"),
                &vl,
                ("overflow policy", "overflow policies"),
                &OVERFLOWS,
            ) {
                out.overflow = i;
            }
        }
        if let Some(v) = t.get("block_timeout_ms") {
            let vl = self.vloc(v, loc);
            if let Some(ms) = self.int_in(
                v,
                &format!("{path}.block_timeout_ms"),
                &vl,
                0,
                i64::MAX,
                "a wait in milliseconds, e.g. 100",
            ) {
                out.timeout_ms = ms.unsigned_abs();
            }
        }
        out
    }

    pub(super) fn modules(
        &mut self,
        item: &Item,
        defaults: InboxDefaults,
        top: &Loc,
    ) -> Vec<ModSpec> {
        let loc = self.vloc(item, top);
        let Some(t) = self.table(item, "modules", &loc) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (name, v) in t.iter() {
            let nloc = self.kloc(t, name, &loc);
            let vl = self.vloc(v, &nloc);
            let path = format!("modules.{}", key_part(name));
            let (id, inbox) = if let Some(mt) = v.as_table_like() {
                self.unknown_keys(mt, &MODULE_KEYS, Some(&path), &vl);
                let id = match mt.get("id") {
                    Some(i) => {
                        let il = self.vloc(i, &vl);
                        self.id16(i, &format!("{path}.id"), &il, "module")
                            .map(|id| (id, il))
                    }
                    None => {
                        self.diag.err_help(
                            &vl,
                            format!("module `{name}` has no `id`"),
                            "add `id = <number>`",
                        );
                        None
                    }
                };
                (
                    id,
                    self.inbox_fields(mt, &path, "inbox_capacity", defaults, &vl),
                )
            } else if v.is_integer() {
                (
                    self.id16(v, &path, &vl, "module")
                        .map(|id| (id, vl.clone())),
                    defaults,
                )
            } else {
                self.wrong_type(
                    &vl,
                    &path,
                    "an id or a table `{ id = …, inbox_capacity = … }`",
                    v,
                    "write `Name = 1` or `Name = { id = 1, inbox_capacity = 64 }`",
                );
                continue;
            };
            if let Some((id, id_loc)) = id {
                out.push(ModSpec {
                    id,
                    id_loc,
                    name: crate::names::nfc(name).into_owned(),
                    inbox: policy(inbox),
                });
            }
        }
        out
    }
}

/// Turns inbox parts into the model's policy.
pub(super) fn policy(d: InboxDefaults) -> InboxConfig {
    InboxConfig {
        capacity: d.capacity,
        overflow: match d.overflow {
            1 => OverflowPolicy::DropNewest,
            2 => OverflowPolicy::Block {
                timeout: Duration::from_millis(d.timeout_ms),
            },
            _ => OverflowPolicy::DropOldest,
        },
    }
}
