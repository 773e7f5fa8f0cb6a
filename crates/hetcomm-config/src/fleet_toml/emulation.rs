//! `emulated` transports: profile, wrapped transport, seed and model parameters.

use super::*;

impl P<'_> {
    pub(super) fn emulated(
        &mut self,
        t: &dyn TableLike,
        path: &str,
        tloc: &Loc,
        spec: &mut TransportSpec,
    ) -> TransportSettings {
        let profile = t.get("profile").and_then(|v| {
            let vl = self.vloc(v, tloc);
            self.choice(
                v,
                &format!("{path}.profile"),
                &vl,
                ("profile", "profiles"),
                &PROFILES,
            )
            .map(|i| PROFILES[i].to_string())
        });
        spec.over = t.get("over").and_then(|v| {
            let vl = self.vloc(v, tloc);
            self.string(
                v,
                &format!("{path}.over"),
                &vl,
                "write the wrapped transport's name in quotes",
            )
            .map(|s| (crate::names::nfc(s).into_owned(), vl))
        });
        let seed = t.get("seed").map_or(0, |v| {
            let vl = self.vloc(v, tloc);
            self.int_in(
                v,
                &format!("{path}.seed"),
                &vl,
                0,
                i64::MAX,
                "a whole number, e.g. 1",
            )
            .map_or(0, i64::unsigned_abs)
        });
        let mut params = BTreeMap::new();
        for (k, v) in t.iter() {
            if !EMULATED_PARAMS.contains(&k) {
                continue;
            }
            let vl = self.vloc(v, tloc);
            let kpath = format!("{path}.{k}");
            let n = match v.as_value() {
                Some(Value::Integer(i)) => *i.value() as f64,
                Some(Value::Float(f)) => *f.value(),
                _ => {
                    self.wrong_type(
                        &vl,
                        &kpath,
                        "a number",
                        v,
                        "write a number without quotes, e.g. 5.0",
                    );
                    continue;
                }
            };
            // Percentages are bounded; decibel-milliwatt levels may be negative; everything
            // else (times, sizes, distances, rates) may not.
            let ok = n.is_finite()
                && if k.ends_with("_percent") {
                    (0.0..=100.0).contains(&n)
                } else if k.ends_with("_dbm") {
                    true
                } else {
                    n >= 0.0
                };
            if !ok {
                let want = if k.ends_with("_percent") {
                    "from 0 to 100"
                } else if k.ends_with("_dbm") {
                    "a finite number"
                } else {
                    "0 or more"
                };
                self.diag.err_help(
                    &vl,
                    format!("`{kpath}` must be {want}, found {}", self.raw(v)),
                    "see docs/config.md for each parameter's unit",
                );
                continue;
            }
            params.insert(k.to_string(), n);
        }
        TransportSettings::Emulated(EmulatedSettings {
            over: spec.over.as_ref().map(|(s, _)| s.clone()),
            profile,
            seed,
            params,
        })
    }
}
