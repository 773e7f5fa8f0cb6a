//! Reading a ROS 2 message from an `.idl` file ([`parse`]), for packages that ship their
//! interfaces as IDL only. The subset read is what rosidl writes and reads for messages:
//!
//! ```text
//! #include "geometry_msgs/msg/Pose.idl"
//! module geometry_msgs { module msg {
//!   typedef double double__36[36];
//!   module PoseWithCovariance_Constants { const uint8 SIZE = 36; };
//!   struct PoseWithCovariance {
//!     geometry_msgs::msg::Pose pose;
//!     @verbatim (language="comment", text="Row-major 6x6.")
//!     double__36 covariance;
//!   };
//! }; };
//! ```
//!
//! Comments (`//`, `/* */`), `#` lines and annotations are skipped, except `@default (value=…)`,
//! which is the field's default. Each member becomes the field its `.msg` spelling would make
//! (IDL `double` is `float64`, `octet` is `byte`, `sequence<T, N>` is `T[<=N]`, `string<N>`
//! is `string<=N`, `pkg::msg::Type` is `pkg/Type`, a typedef'd array is `T[N]`), so a type
//! read from IDL has the same schema and type hash as from its `.msg`. IDL `char`, `wchar`,
//! `long double`, unions and enums are refused (no `.msg` type is written as them).
//! Errors are at `file:line`, like [`crate::msgfile`]'s.

use std::collections::HashMap;

use crate::msgfile::{self, Base, Constant, Field, MsgFile, ParseError};
use crate::schema::Flavour;

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Word(String),
    Num(String),
    Str(String),
    Punct(char),
}

/// Splits `text` into tokens with their lines; comments and `#` lines are skipped.
fn tokens(text: &str) -> Result<Vec<(usize, Tok)>, (usize, String)> {
    let chars: Vec<char> = text.chars().collect();
    let (mut i, mut line, mut out) = (0, 1, Vec::new());
    let mut at_line_start = true;
    while i < chars.len() {
        let c = chars[i];
        if c == '\n' {
            line += 1;
            at_line_start = true;
            i += 1;
            continue;
        }
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        if c == '#' && at_line_start {
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
            continue;
        }
        at_line_start = false;
        if c == '/' && chars.get(i + 1) == Some(&'/') {
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && chars.get(i + 1) == Some(&'*') {
            let start = line;
            i += 2;
            loop {
                match chars.get(i) {
                    None => return Err((start, "a `/*` comment is never closed".into())),
                    Some('*') if chars.get(i + 1) == Some(&'/') => break,
                    Some('\n') => line += 1,
                    _ => {}
                }
                i += 1;
            }
            i += 2;
        } else if c == '"' {
            let start = line;
            let mut s = String::new();
            i += 1;
            loop {
                match chars.get(i) {
                    None => return Err((start, "a string is never closed".into())),
                    Some('"') => break,
                    Some('\\') => {
                        s.push(chars.get(i + 1).copied().unwrap_or('\\'));
                        i += 1;
                    }
                    Some('\n') => {
                        line += 1;
                        s.push('\n');
                    }
                    Some(&ch) => s.push(ch),
                }
                i += 1;
            }
            i += 1;
            out.push((start, Tok::Str(s)));
        } else if c.is_ascii_alphabetic() || c == '_' {
            let mut w = String::new();
            while i < chars.len()
                && (chars[i].is_ascii_alphanumeric()
                    || chars[i] == '_'
                    || (chars[i] == ':' && chars.get(i + 1) == Some(&':')))
            {
                if chars[i] == ':' {
                    w.push_str("::");
                    i += 2;
                } else {
                    w.push(chars[i]);
                    i += 1;
                }
            }
            out.push((line, Tok::Word(w)));
        } else if c.is_ascii_digit()
            || ((c == '-' || c == '.') && chars.get(i + 1).is_some_and(|d| d.is_ascii_digit()))
        {
            let mut n = String::from(c);
            i += 1;
            while i < chars.len()
                && (chars[i].is_ascii_alphanumeric() || matches!(chars[i], '.' | '+' | '-'))
            {
                // A sign belongs to the number only after an exponent's `e`.
                if matches!(chars[i], '+' | '-') && !n.ends_with(['e', 'E']) {
                    break;
                }
                n.push(chars[i]);
                i += 1;
            }
            out.push((line, Tok::Num(n)));
        } else if "{}<>;,[]()=@".contains(c) {
            out.push((line, Tok::Punct(c)));
            i += 1;
        } else {
            return Err((line, format!("unexpected `{c}`")));
        }
    }
    Ok(out)
}

/// A member or typedef's type, as a `.msg` would spell it without its array part.
struct Spelled {
    base: String,
    /// `[<=N]` or `[]` when the IDL type is a sequence.
    sequence: Option<String>,
}

struct Parser<'a> {
    toks: Vec<(usize, Tok)>,
    at: usize,
    file: &'a str,
    package: &'a str,
    name: &'a str,
    /// Typedefs seen so far: name → (`.msg` spelling of the element, array suffix).
    typedefs: HashMap<String, (String, String)>,
    modules: Vec<String>,
    out: MsgFile,
    found: bool,
}

impl Parser<'_> {
    fn line(&self) -> usize {
        self.toks
            .get(self.at)
            .or(self.toks.last())
            .map_or(1, |t| t.0)
    }

    fn err(&self, what: impl Into<String>) -> ParseError {
        ParseError {
            file: self.file.to_string(),
            line: self.line(),
            what: what.into(),
        }
    }

    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.at).map(|t| &t.1)
    }

    fn next(&mut self) -> Result<Tok, ParseError> {
        let t = self
            .toks
            .get(self.at)
            .map(|t| t.1.clone())
            .ok_or_else(|| self.err("the file ends inside a declaration"))?;
        self.at += 1;
        Ok(t)
    }

    fn punct(&mut self, c: char) -> Result<(), ParseError> {
        match self.next()? {
            Tok::Punct(p) if p == c => Ok(()),
            other => {
                self.at -= 1;
                Err(self.err(format!("expected `{c}`, found {}", show(&other))))
            }
        }
    }

    fn eat(&mut self, c: char) -> bool {
        if self.peek() == Some(&Tok::Punct(c)) {
            self.at += 1;
            true
        } else {
            false
        }
    }

    fn word(&mut self) -> Result<String, ParseError> {
        match self.next()? {
            Tok::Word(w) => Ok(w),
            other => {
                self.at -= 1;
                Err(self.err(format!("expected a name, found {}", show(&other))))
            }
        }
    }

    fn size(&mut self) -> Result<String, ParseError> {
        match self.next()? {
            Tok::Num(n) => Ok(n),
            other => {
                self.at -= 1;
                Err(self.err(format!("expected a size, found {}", show(&other))))
            }
        }
    }

    /// Annotations before a declaration; the value of `@default (value=…)` if one is there.
    fn annotations(&mut self) -> Result<Option<String>, ParseError> {
        let mut default = None;
        while self.eat('@') {
            let name = self.word()?;
            if !self.eat('(') {
                continue;
            }
            let mut depth = 1;
            let mut key = None;
            while depth > 0 {
                match self.next()? {
                    Tok::Punct('(') => depth += 1,
                    Tok::Punct(')') => depth -= 1,
                    Tok::Word(w) if depth == 1 && self.peek() == Some(&Tok::Punct('=')) => {
                        key = Some(w);
                    }
                    Tok::Punct('=') if name == "default" && key.as_deref() == Some("value") => {
                        default = Some(match self.next()? {
                            Tok::Str(s) => format!("\"{s}\""),
                            Tok::Num(n) | Tok::Word(n) => n,
                            other => {
                                return Err(self.err(format!(
                                "`@default` has value {}: expected a number, a name or a string",
                                show(&other)
                            )))
                            }
                        });
                    }
                    _ => {}
                }
            }
        }
        Ok(default)
    }

    /// A type specifier, in `.msg` spelling.
    fn type_spec(&mut self) -> Result<Spelled, ParseError> {
        let w = self.word()?;
        let plain = |base: &str| Spelled {
            base: base.to_string(),
            sequence: None,
        };
        Ok(match w.as_str() {
            "boolean" => plain("bool"),
            "octet" => plain("byte"),
            "int8" | "uint8" | "int16" | "uint16" | "int32" | "uint32" | "int64" | "uint64" => {
                plain(&w)
            }
            "float" => plain("float32"),
            "double" => plain("float64"),
            "short" => plain("int16"),
            "long" if self.peek() == Some(&Tok::Word("long".into())) => {
                self.at += 1;
                plain("int64")
            }
            "long" if self.peek() == Some(&Tok::Word("double".into())) => {
                return Err(self.err("`long double` has no ROS message type: use `double`"))
            }
            "long" => plain("int32"),
            "unsigned" => match self.word()?.as_str() {
                "short" => plain("uint16"),
                "long" if self.peek() == Some(&Tok::Word("long".into())) => {
                    self.at += 1;
                    plain("uint64")
                }
                "long" => plain("uint32"),
                other => return Err(self.err(format!("`unsigned {other}` is not an IDL type"))),
            },
            "char" | "wchar" => {
                return Err(self.err(format!(
                    "IDL `{w}` is not converted by the bridges (a `.msg` `char` is IDL `uint8`)"
                )))
            }
            "string" | "wstring" => {
                if self.eat('<') {
                    let n = self.size()?;
                    self.punct('>')?;
                    plain(&format!("{w}<={n}"))
                } else {
                    plain(&w)
                }
            }
            "sequence" => {
                self.punct('<')?;
                let elem = self.type_spec()?;
                if elem.sequence.is_some() {
                    return Err(self.err("a sequence of sequences has no ROS message type"));
                }
                let bound = if self.eat(',') {
                    format!("[<={}]", self.size()?)
                } else {
                    "[]".to_string()
                };
                self.punct('>')?;
                Spelled {
                    base: elem.base,
                    sequence: Some(bound),
                }
            }
            "union" | "enum" => {
                return Err(self.err(format!("an IDL `{w}` has no ROS message type")))
            }
            scoped if scoped.contains("::") => {
                let parts: Vec<&str> = scoped.trim_start_matches("::").split("::").collect();
                match parts[..] {
                    [pkg, "msg", ty] => plain(&format!("{pkg}/{ty}")),
                    _ => {
                        return Err(self.err(format!(
                            "`{scoped}` is not a message type: write `pkg::msg::Type`"
                        )))
                    }
                }
            }
            name => match self.typedefs.get(name) {
                Some((base, suffix)) => Spelled {
                    base: base.clone(),
                    sequence: Some(suffix.clone()),
                },
                None => plain(&format!("{}/{name}", self.package)),
            },
        })
    }

    /// `NAME` or `NAME[N]` after a type: the name and the array suffix.
    fn declarator(&mut self) -> Result<(String, Option<String>), ParseError> {
        let name = self.word()?;
        if self.eat('[') {
            let n = self.size()?;
            self.punct(']')?;
            if self.peek() == Some(&Tok::Punct('[')) {
                return Err(self.err("a multi-dimensional array has no ROS message type"));
            }
            return Ok((name, Some(format!("[{n}]"))));
        }
        Ok((name, None))
    }

    /// The `.msg` text of a type with at most one array part.
    fn spell(&self, ty: Spelled, array: Option<String>) -> Result<String, ParseError> {
        match (ty.sequence, array) {
            (Some(_), Some(_)) => Err(self.err("an array of arrays has no ROS message type")),
            (Some(s), None) | (None, Some(s)) => Ok(format!("{}{s}", ty.base)),
            (None, None) => Ok(ty.base),
        }
    }

    /// Declarations until `}` (or the end, at the top).
    fn declarations(&mut self) -> Result<(), ParseError> {
        loop {
            match self.peek() {
                None => return Ok(()),
                Some(Tok::Punct('}')) => return Ok(()),
                _ => {}
            }
            self.annotations()?;
            let line = self.line();
            match self.word()?.as_str() {
                "module" => {
                    let name = self.word()?;
                    self.punct('{')?;
                    self.modules.push(name);
                    self.declarations()?;
                    self.modules.pop();
                    self.punct('}')?;
                }
                "typedef" => {
                    let ty = self.type_spec()?;
                    let (name, array) = self.declarator()?;
                    let (base, suffix) = match (ty.sequence, array) {
                        (Some(s), None) | (None, Some(s)) => (ty.base, s),
                        (None, None) => {
                            return Err(self.err(format!(
                                "typedef `{name}` names a type that is not an array: write \
                                 the type itself"
                            )))
                        }
                        (Some(_), Some(_)) => {
                            return Err(self.err("an array of arrays has no ROS message type"))
                        }
                    };
                    self.typedefs.insert(name, (base, suffix));
                }
                "const" => {
                    let ty = self.type_spec()?;
                    let ty = self.spell(ty, None)?;
                    let name = self.word()?;
                    self.punct('=')?;
                    let value = match self.next()? {
                        Tok::Str(s) => format!("\"{s}\""),
                        Tok::Num(n) | Tok::Word(n) => n,
                        other => {
                            return Err(
                                self.err(format!("constant `{name}` has value {}", show(&other)))
                            )
                        }
                    };
                    if self.in_constants() {
                        self.constant(line, &ty, &name, &value)?;
                    }
                }
                "struct" => {
                    let name = self.word()?;
                    self.punct('{')?;
                    let ours = self.modules == [self.package, "msg"] && name == self.name;
                    while !self.eat('}') {
                        let default = self.annotations()?;
                        let line = self.line();
                        let ty = self.type_spec()?;
                        let (fname, array) = self.declarator()?;
                        self.punct(';')?;
                        if ours {
                            let text = self.spell(ty, array)?;
                            self.field(line, &text, &fname, default)?;
                        }
                    }
                    if ours {
                        self.found = true;
                    }
                }
                other => {
                    self.at -= 1;
                    return Err(self.err(format!(
                        "unexpected `{other}`: a message's IDL has modules, typedefs, \
                         constants and one struct"
                    )));
                }
            }
            self.punct(';')?;
        }
    }

    /// Whether the declarations being read are `PKG::msg::NAME_Constants`.
    fn in_constants(&self) -> bool {
        let constants = format!("{}_Constants", self.name);
        self.modules.len() == 3
            && self.modules[0] == self.package
            && self.modules[1] == "msg"
            && self.modules[2] == constants
    }

    fn parse_error(&self, line: usize, what: String) -> ParseError {
        ParseError {
            file: self.file.to_string(),
            line,
            what,
        }
    }

    fn field(
        &mut self,
        line: usize,
        text: &str,
        name: &str,
        default: Option<String>,
    ) -> Result<(), ParseError> {
        let ty = msgfile::parse_type(text, self.package, Flavour::Ros2)
            .map_err(|what| self.parse_error(line, what))?;
        if !msgfile::valid_field(name, Flavour::Ros2) {
            return Err(self.parse_error(line, format!("`{name}` is not a field name")));
        }
        if self.out.fields.iter().any(|f| f.name == name) {
            return Err(self.parse_error(line, format!("field `{name}` is declared twice")));
        }
        self.out.fields.push(Field {
            name: name.to_string(),
            ty,
            default,
            line,
        });
        Ok(())
    }

    fn constant(
        &mut self,
        line: usize,
        text: &str,
        name: &str,
        value: &str,
    ) -> Result<(), ParseError> {
        let ty = msgfile::parse_type(text, self.package, Flavour::Ros2)
            .map_err(|what| self.parse_error(line, what))?;
        if !matches!(ty.base, Base::Prim(_) | Base::Str(_)) {
            return Err(self.parse_error(
                line,
                format!(
                    "constant `{name}` is of type `{text}`: a constant is a primitive or a string"
                ),
            ));
        }
        let value = msgfile::constant_value(&ty.base, value)
            .map_err(|why| self.parse_error(line, format!("constant `{name}`: {why}")))?;
        self.out.constants.push(Constant {
            ty: text.to_string(),
            name: name.to_string(),
            value,
        });
        Ok(())
    }
}

fn show(t: &Tok) -> String {
    match t {
        Tok::Word(w) | Tok::Num(w) => format!("`{w}`"),
        Tok::Str(s) => format!("the string \"{s}\""),
        Tok::Punct(c) => format!("`{c}`"),
    }
}

/// Reads the IDL text of ROS 2 message `package/name` (`file` names it in errors): its
/// struct `package::msg::name` and constants module `package::msg::name_Constants`.
pub fn parse(text: &str, file: &str, package: &str, name: &str) -> Result<MsgFile, ParseError> {
    let toks = tokens(text).map_err(|(line, what)| ParseError {
        file: file.to_string(),
        line,
        what,
    })?;
    let mut p = Parser {
        toks,
        at: 0,
        file,
        package,
        name,
        typedefs: HashMap::new(),
        modules: Vec::new(),
        out: MsgFile {
            name: format!("{package}/{name}"),
            fields: Vec::new(),
            constants: Vec::new(),
            text: text.to_string(),
            file: file.to_string(),
        },
        found: false,
    };
    p.declarations()?;
    if p.peek().is_some() {
        return Err(p.err("unexpected `}`: it closes no module"));
    }
    if !p.found {
        return Err(ParseError {
            file: file.to_string(),
            line: 1,
            what: format!("no `struct {name}` in `module {package} {{ module msg {{ … }}; }};`"),
        });
    }
    // rosidl writes an empty message's IDL with this one member, which its `.msg` lacks.
    if p.out.fields.len() == 1 && p.out.fields[0].name == "structure_needs_at_least_one_member" {
        p.out.fields.clear();
    }
    Ok(p.out)
}
