use hetcomm_config::*;
use std::path::Path;
#[test]
fn scratch() {
    let e = load_legacy(
        Path::new("/tmp/scr/ids.txt"),
        Path::new("/tmp/scr/table.txt"),
        None,
    );
    println!("A:\n{}", e.unwrap_err());
    let t = "[systems]\nAlpha = 0\nCharlie = 1\nTango = 1\n[transports.R]\nkind=\"inproc\"\n[letters]\nR = \"R\"\n[table]\ncolumns = [\"Alpha\", \"Charlie\", \"Tango\", 1]\nAlpha = [\"X\", \"R\", \"R\", \"Q\"]\nCharlie = [\"R\", \"X\", \"R\", \"X\"]\nTango = [\"R\", \"R\", \"X\", \"X\"]\nZulu = []\n";
    println!("B:\n{}", parse_str(t, "b.toml", None).unwrap_err());
}
