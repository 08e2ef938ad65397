//! A small reader of protobuf text format, enough for camera files such as KeyPose's `.pbtxt`.
//!
//! **Why by hand.** The protobuf crates need the message schema compiled in to parse text format,
//! which would tie trand to each dataset's `.proto`. This is a tokenizer and a tree of `key: value`
//! and `key { ... }` (or `key: { ... }`) entries, with `#` comments and quoted strings; `< >`
//! blocks, `[ ]` lists and `,`/`;` separators are not read. Errors name the line.

/// A parsed text protobuf: entries in file order (repeated fields repeat).
#[derive(Debug, Default)]
pub struct TextProto(Vec<(String, Entry)>);

#[derive(Debug)]
enum Entry {
    Scalar(String),
    Block(TextProto),
}

/// A token and the line it starts on (1-based).
struct Token {
    text: String,
    line: usize,
}

impl TextProto {
    /// Parses `text`; the error says what was expected on which line.
    pub fn parse(text: &str) -> Result<Self, String> {
        let tokens = tokenize(text)?;
        let mut pos = 0;
        let tree = Self::block(&tokens, &mut pos)?;
        match tokens.get(pos) {
            None => Ok(tree),
            Some(t) => Err(format!("line {}: unexpected `{}`", t.line, t.text)),
        }
    }

    fn block(tokens: &[Token], pos: &mut usize) -> Result<Self, String> {
        let text = |i: usize| tokens.get(i).map(|t| t.text.as_str());
        let mut out = Vec::new();
        while let Some(key) = tokens.get(*pos) {
            if key.text == "}" {
                break;
            }
            let at = format!("line {}: `{}`", key.line, key.text);
            *pos += 1;
            if text(*pos) == Some(":") && text(*pos + 1) != Some("{") {
                let value = tokens
                    .get(*pos + 1)
                    .filter(|v| !["{", "}", ":"].contains(&v.text.as_str()))
                    .ok_or_else(|| format!("{at}: `:` without a value"))?;
                *pos += 2;
                out.push((key.text.clone(), Entry::Scalar(value.text.clone())));
                continue;
            }
            if text(*pos) == Some(":") {
                *pos += 1;
            }
            if text(*pos) != Some("{") {
                return Err(format!("{at}: expected `:` or `{{` after it"));
            }
            *pos += 1;
            let inner = Self::block(tokens, pos)?;
            if text(*pos) != Some("}") {
                return Err(format!("{at}: its `{{` is not closed"));
            }
            *pos += 1;
            out.push((key.text.clone(), Entry::Block(inner)));
        }
        Ok(Self(out))
    }

    /// The first block named `key`.
    pub fn block_of<'a>(&'a self, key: &'a str) -> Option<&'a TextProto> {
        self.blocks(key).next()
    }

    /// Every block named `key`, in order.
    pub fn blocks<'a>(&'a self, key: &'a str) -> impl Iterator<Item = &'a TextProto> {
        self.0.iter().filter_map(move |(k, e)| match e {
            Entry::Block(b) if k == key => Some(b),
            _ => None,
        })
    }

    /// Every number named `key`, in order; `None` if one of them is not a number.
    pub fn numbers(&self, key: &str) -> Option<Vec<f64>> {
        self.0
            .iter()
            .filter(|(k, _)| k == key)
            .map(|(_, e)| match e {
                Entry::Scalar(s) => s.parse().ok(),
                Entry::Block(_) => None,
            })
            .collect()
    }

    /// The first number named `key`.
    pub fn number(&self, key: &str) -> Option<f64> {
        self.numbers(key)?.first().copied()
    }
}

fn tokenize(text: &str) -> Result<Vec<Token>, String> {
    let mut out = Vec::new();
    let mut line = 1;
    let mut chars = text.chars().peekable();
    while let Some(&c) = chars.peek() {
        let start = line;
        match c {
            '\n' => {
                line += 1;
                chars.next();
            }
            c if c.is_whitespace() => {
                chars.next();
            }
            '#' => while chars.next_if(|&x| x != '\n').is_some() {},
            '{' | '}' | ':' => {
                chars.next();
                out.push(Token {
                    text: c.to_string(),
                    line,
                });
            }
            '"' | '\'' => {
                chars.next();
                let mut s = String::new();
                loop {
                    match chars.next() {
                        Some(q) if q == c => break,
                        Some('\\') => s.extend(chars.next()),
                        Some(x) => {
                            line += usize::from(x == '\n');
                            s.push(x);
                        }
                        None => return Err(format!("line {start}: unterminated string")),
                    }
                }
                out.push(Token {
                    text: s,
                    line: start,
                });
            }
            _ => {
                let mut s = String::new();
                while let Some(x) = chars.next_if(|&x| !x.is_whitespace() && !"{}:#\"'".contains(x))
                {
                    s.push(x);
                }
                out.push(Token { text: s, line });
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_repeated_fields_comments_strings_and_colon_blocks_are_read() {
        let p = TextProto::parse(
            "a {\n  e: 1\n  e: -2.5e-1  # note\n  b { x: 3 }\n}\nb: { x: 4 }\nname: \"q } r\"\n",
        )
        .unwrap();
        let a = p.block_of("a").unwrap();
        assert_eq!(a.numbers("e"), Some(vec![1.0, -0.25]));
        assert_eq!(a.block_of("b").unwrap().number("x"), Some(3.0));
        assert_eq!(p.block_of("b").unwrap().number("x"), Some(4.0));
        assert_eq!(p.blocks("b").count(), 1);
        assert!(p.block_of("name").is_none());
        assert_eq!(p.numbers("name"), None);
    }

    #[test]
    fn malformed_text_is_an_error_naming_its_line() {
        let e = TextProto::parse("a {\n b: 1\n c d\n}").unwrap_err();
        assert!(e.contains("line 3") && e.contains("`c`"), "{e}");
        let e = TextProto::parse("a {\n b: 1\n").unwrap_err();
        assert!(e.contains("line 1") && e.contains("not closed"), "{e}");
        let e = TextProto::parse("x: 1\n}\n").unwrap_err();
        assert!(e.contains("line 2"), "{e}");
        assert!(TextProto::parse("x: \"open").is_err());
        assert!(TextProto::parse("x:").is_err());
    }
}
