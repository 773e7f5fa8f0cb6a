//! Synthetic fleets for scale tests and benchmarks: one generator, so that the tests that
//! check big fleets validate right and the benchmark that times them read the same file.

use std::fmt::Write;

/// A fleet of `n` systems `S0 … S{n-1}`, each with a UDP endpoint on transport `lan`, an
/// emulated `wifi` over it, an in-process `local` and the letter `L` for `lan`. With `table`,
/// every off-diagonal cell of the communication table carries traffic, cycling through a
/// transport name, an emulated transport, a letter and an in-process transport; without, the
/// fleet has no `[table]` (every pair is `X`).
pub fn scale_fleet_text(n: usize, table: bool) -> String {
    let cells = if table { n * n * 7 } else { 0 };
    let mut t = String::with_capacity(cells + n * 64);
    t.push_str("name = \"scale\"\n\n[systems]\n");
    for i in 0..n {
        let _ = writeln!(t, "S{i} = {i}");
    }
    t.push_str("\n[transports.lan]\nkind = \"udp\"\n\n[transports.lan.endpoints]\n");
    for i in 0..n {
        let _ = writeln!(t, "S{i} = \"10.{}.{}.1:7400\"", i / 250, i % 250);
    }
    t.push_str("\n[transports.wifi]\nkind = \"emulated\"\nprofile = \"wifi\"\nover = \"lan\"\n");
    t.push_str("\n[transports.local]\nkind = \"inproc\"\n\n[letters]\nL = \"lan\"\n");
    if !table {
        return t;
    }
    t.push_str("\n[table]\ncolumns = [");
    for i in 0..n {
        let _ = write!(t, "{}\"S{i}\"", if i == 0 { "" } else { ", " });
    }
    t.push_str("]\n");
    const CELLS: [&str; 4] = ["lan", "wifi", "L", "local"];
    for i in 0..n {
        let _ = write!(t, "S{i} = [");
        for j in 0..n {
            let cell = if i == j { "X" } else { CELLS[(i + j) % 4] };
            t.push_str(if j == 0 { "\"" } else { ", \"" });
            t.push_str(cell);
            t.push('"');
        }
        t.push_str("]\n");
    }
    t
}
