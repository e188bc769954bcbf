//! Tokens of the model language, each with its 1-based character column and byte range
//! (the byte range lets `substitute` splice coefficient values into the user's own text).

use super::ModelError;

/// What a token is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Tok {
    Num(f64),
    Ident,
    Plus,
    Minus,
    Star,
    Slash,
    Caret,
    LParen,
    RParen,
    Comma,
    Eq,
}

/// A token and where it sits in the source.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Token {
    pub tok: Tok,
    /// 1-based character column of the first character.
    pub col: usize,
    /// Byte range in the source.
    pub start: usize,
    pub end: usize,
}

impl Token {
    /// The token's source text.
    pub fn text<'s>(&self, src: &'s str) -> &'s str {
        &src[self.start..self.end]
    }
}

fn is_ident_start(c: char) -> bool {
    c.is_ascii_alphabetic() || c == '_'
}

fn is_ident_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Splits `src` into tokens. Never panics; any character outside the language is an error
/// naming the character and its column.
pub(crate) fn lex(src: &str) -> Result<Vec<Token>, ModelError> {
    let chars: Vec<(usize, char)> = src.char_indices().collect();
    let byte_at = |i: usize| chars.get(i).map_or(src.len(), |&(b, _)| b);
    let ch = |i: usize| chars.get(i).map(|&(_, c)| c);
    let mut toks = Vec::new();
    let mut i = 0;
    while let Some(c) = ch(i) {
        let col = i + 1;
        let start = byte_at(i);
        if c.is_whitespace() {
            i += 1;
            continue;
        }
        let simple = match c {
            '+' => Some(Tok::Plus),
            '-' => Some(Tok::Minus),
            '*' => Some(Tok::Star),
            '/' => Some(Tok::Slash),
            '^' => Some(Tok::Caret),
            '(' => Some(Tok::LParen),
            ')' => Some(Tok::RParen),
            ',' => Some(Tok::Comma),
            '=' => Some(Tok::Eq),
            _ => None,
        };
        if let Some(tok) = simple {
            i += 1;
            toks.push(Token {
                tok,
                col,
                start,
                end: byte_at(i),
            });
            continue;
        }
        let digit = |j: usize| ch(j).is_some_and(|c| c.is_ascii_digit());
        if c.is_ascii_digit() || (c == '.' && digit(i + 1)) {
            let mut j = i;
            while digit(j) {
                j += 1;
            }
            if ch(j) == Some('.') {
                j += 1;
                while digit(j) {
                    j += 1;
                }
            }
            if matches!(ch(j), Some('e' | 'E')) {
                let mut k = j + 1;
                if matches!(ch(k), Some('+' | '-')) {
                    k += 1;
                }
                if digit(k) {
                    while digit(k) {
                        k += 1;
                    }
                    j = k;
                } else {
                    // `2e`, `2e+`, `2ex`: an exponent with no digits.
                    let mut k = j + 1;
                    while ch(k).is_some_and(is_ident_char) {
                        k += 1;
                    }
                    let text = &src[start..byte_at(k)];
                    return Err(ModelError {
                        message: format!("malformed number '{text}' at column {col}"),
                        column: Some(col),
                    });
                }
            }
            let end = byte_at(j);
            let text = &src[start..end];
            let value: f64 = text.parse().map_err(|_| ModelError {
                message: format!("malformed number '{text}' at column {col}"),
                column: Some(col),
            })?;
            if !value.is_finite() {
                return Err(ModelError {
                    message: format!("number '{text}' at column {col} is too large"),
                    column: Some(col),
                });
            }
            toks.push(Token {
                tok: Tok::Num(value),
                col,
                start,
                end,
            });
            i = j;
            continue;
        }
        if is_ident_start(c) {
            let mut j = i + 1;
            while ch(j).is_some_and(is_ident_char) {
                j += 1;
            }
            toks.push(Token {
                tok: Tok::Ident,
                col,
                start,
                end: byte_at(j),
            });
            i = j;
            continue;
        }
        return Err(ModelError {
            message: format!(
                "unexpected character '{}' at column {col}",
                c.escape_debug()
            ),
            column: Some(col),
        });
    }
    Ok(toks)
}
