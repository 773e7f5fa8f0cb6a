//! `[table]`: the communication table's `columns` and one row per source system.

use super::*;

impl P<'_> {
    pub(super) fn comm_table(&mut self, item: &Item, top: &Loc) -> Option<RawTable> {
        let loc = self.vloc(item, top);
        let t = self.table(item, "table", &loc)?;
        let mut columns = Vec::new();
        let Some(c) = t.get("columns") else {
            // A typo of `columns` would otherwise read as a row of an unknown system.
            let mut typo = false;
            for (k, _) in t.iter() {
                if suggest::closest(k, &["columns"]).is_some() {
                    let kl = self.kloc(t, k, &loc);
                    self.diag.err_help(
                        &kl,
                        format!("unknown key `{k}` in `table`"),
                        "did you mean `columns`?",
                    );
                    typo = true;
                }
            }
            if !typo && t.iter().next().is_some() {
                self.diag.err_help(
                    &loc,
                    "the table has no `columns`",
                    "add `columns = [\"Alpha\", …]`: the destination systems, in cell order",
                );
            }
            return None;
        };
        let cl = self.vloc(c, &loc);
        let Some(arr) = c.as_array() else {
            self.wrong_type(
                &cl,
                "table.columns",
                "an array of system names",
                c,
                "e.g. `columns = [\"Alpha\", \"Charlie\"]`",
            );
            return None; // without columns, every row would be reported as ragged
        };
        let mut columns_ok = true;
        for v in arr.iter() {
            let vl = self.at(v.span(), &cl);
            match v {
                Value::String(s) => columns.push(label(s.value(), &vl)),
                Value::Integer(i) => columns.push(Label {
                    text: i.value().to_string(),
                    loc: vl,
                    by_id: true,
                }),
                other => {
                    let found = format!(
                        "{} `{}`",
                        type_name(&Item::Value(other.clone())),
                        other
                            .span()
                            .and_then(|r| self.text.get(r))
                            .unwrap_or("")
                            .trim()
                    );
                    self.diag.err_help(
                        &vl,
                        format!("`table.columns` must list system names, found {found}"),
                        "e.g. `columns = [\"Alpha\", \"Charlie\"]`",
                    );
                    columns_ok = false;
                }
            }
        }
        if !columns_ok {
            return None;
        }
        let mut table = RawTable::new(self.file.clone(), loc.clone(), columns);
        for (k, v) in t.iter() {
            if k == "columns" {
                continue;
            }
            let kl = self.kloc(t, k, &loc);
            let vl = self.vloc(v, &kl);
            let path = format!("table.{}", key_part(k));
            let Some(arr) = v.as_array() else {
                self.wrong_type(
                    &vl,
                    &path,
                    "an array of cells",
                    v,
                    "e.g. `Alpha = [\"X\", \"wired\"]`: one transport name, letter or X per column",
                );
                continue;
            };
            table.start_row(label(k, &kl));
            for c in arr.iter() {
                let cl = self.at(c.span(), &vl);
                match c.as_str() {
                    Some(s) => table.push_cell(s, cl.line, cl.column),
                    None => {
                        let found = format!(
                            "{} `{}`",
                            type_name(&Item::Value(c.clone())),
                            c.span().and_then(|r| self.text.get(r)).unwrap_or("").trim()
                        );
                        self.diag.err_help(
                            &cl,
                            format!("`{path}` cells must be strings, found {found}"),
                            "write a transport name, a letter or \"X\" in quotes",
                        );
                        // A placeholder keeps the row's length right for the shape checks.
                        table.push_cell("X", cl.line, cl.column);
                    }
                }
            }
        }
        Some(table)
    }
}
