//! `hetcomm::security_lines`, what `hetcomm validate` prints: each transport's protection as
//! this program opens it (the registry's answer), not as the config crate alone would guess.

fn fleet(extra: &str) -> hetcomm::config::Fleet {
    let text = format!(
        r#"[systems]
A = 0
B = 1

[transports.w]
kind = "inproc"

[transports.e]
kind = "emulated"
over = "u"
profile = "wifi"

[transports.u]
kind = "udp"
endpoints = {{ A = "127.0.0.1:0", B = "127.0.0.1:0" }}

[transports.open]
kind = "tcp"
security = "none"
endpoints = {{ A = "127.0.0.1:0", B = "127.0.0.1:0" }}

[table]
columns = ["A", "B"]
A = ["X", "w"]
B = ["e", "X"]
{extra}"#
    );
    hetcomm::parse_fleet(&text, "f.toml", None).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn each_transport_line_says_what_protects_it_where_it_is_opened() {
    let f = fleet("");
    assert_eq!(
        hetcomm::security_lines(&f),
        [
            "transport `w` (inproc): in-process: frames never leave the process",
            // An emulated transport over `u` travels on `u`'s sealed link.
            "transport `e` (emulated): secured; 2 of the 2 systems it carries have no public key: A, B",
            // `e`'s frames travel on `u`'s link: its systems need keys there too.
            "transport `u` (udp): secured; 2 of the 2 systems it carries have no public key: A, B",
            "transport `open` (tcp): NOT SECURED (security = \"none\"): anyone who can reach it can pose as any system",
        ]
    );
    // The config crate alone judges by the table's pairs only.
    assert_eq!(
        f.security_lines()[2],
        "transport `u` (udp): secured; carries no traffic"
    );
    assert_eq!(hetcomm::security_lines(&f)[..2], f.security_lines()[..2]);
}

#[test]
fn in_process_security_makes_in_process_lines_secured() {
    let f = fleet("\n[security]\nin_process = true\n");
    let lines = hetcomm::security_lines(&f);
    assert_eq!(
        lines[0],
        "transport `w` (inproc): secured; 2 of the 2 systems it carries have no public key: A, B"
    );
    // The config crate alone does not know that `inproc` is then sealed.
    assert_eq!(
        f.security_lines()[0],
        "transport `w` (inproc): in-process: frames never leave the process"
    );
}

#[test]
fn a_layered_transport_over_an_unsecured_one_is_said_not_secured() {
    let text = r#"[systems]
A = 0
B = 1

[transports.e]
kind = "emulated"
over = "t"
profile = "wifi"

[transports.t]
kind = "tcp"
security = "none"
endpoints = { A = "127.0.0.1:0", B = "127.0.0.1:0" }

[table]
columns = ["A", "B"]
A = ["X", "e"]
B = ["e", "X"]
"#;
    let f = hetcomm::parse_fleet(text, "f.toml", None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        hetcomm::security_lines(&f),
        [
            "transport `e` (emulated): NOT SECURED: its frames travel on a transport with \
             `security = \"none\"`",
            "transport `t` (tcp): NOT SECURED (security = \"none\"): anyone who can reach it can \
             pose as any system",
        ]
    );
}
