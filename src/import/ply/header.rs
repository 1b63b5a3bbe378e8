//! The PLY header: its text, `ply` … `end_header`, → [`Header`], the encoding and the element
//! and property layouts the body readers follow.

use crate::import::ImportError;

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    /// Parses a type name as the PLY spec and common writers spell it.
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Size in bytes in binary encodings.
    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    pub(super) fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

/// The type of one property.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum PropertyType {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
pub(super) struct Property {
    pub(super) name: String,
    pub(super) ty: PropertyType,
}

#[derive(Clone, Debug)]
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: u64,
    pub(super) properties: Vec<Property>,
}

impl Element {
    /// Byte size of one entry when the element has no list property.
    pub(super) fn fixed_stride(&self) -> Option<usize> {
        self.properties
            .iter()
            .map(|p| match p.ty {
                PropertyType::Scalar(s) => Some(s.size()),
                PropertyType::List { .. } => None,
            })
            .sum()
    }

    pub(super) fn property_index(&self, name: &str) -> Option<usize> {
        self.properties.iter().position(|p| p.name == name)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

/// The parsed header.
#[derive(Clone, Debug)]
pub(super) struct Header {
    pub(super) encoding: Encoding,
    pub(super) elements: Vec<Element>,
    /// `obj_info num_cols N` and `obj_info num_rows N`: a range grid's size.
    pub(super) grid_size: (Option<usize>, Option<usize>),
    /// Byte offset of the first payload byte.
    pub(super) body_start: usize,
    /// Line number of the first payload line (ascii).
    pub(super) body_line: usize,
}

/// Parses the header lines up to and including `end_header`.
pub(super) fn read_header(bytes: &[u8], path: &str) -> Result<Header, ImportError> {
    let bad = |line: usize, message: String| ImportError::BadHeader {
        path: path.to_owned(),
        line,
        message,
    };
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut grid_size = (None, None);
    let mut offset = 0;
    let mut line_number = 0;
    loop {
        let rest = &bytes[offset..];
        let Some(len) = rest.iter().position(|&b| b == b'\n') else {
            return Err(ImportError::Truncated {
                path: path.to_owned(),
                detail: "the ply header has no `end_header` line".to_owned(),
            });
        };
        line_number += 1;
        offset += len + 1;
        let raw = &rest[..len];
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let Ok(line) = std::str::from_utf8(raw) else {
            return Err(bad(
                line_number,
                "the line is not text; the header must be ascii".into(),
            ));
        };
        let mut words = line.split_ascii_whitespace();
        let keyword = words.next().unwrap_or("");
        if line_number == 1 {
            if line.trim_end() != "ply" {
                return Err(bad(1, "the first line must be `ply`".into()));
            }
            continue;
        }
        match keyword {
            "format" => {
                let (Some(name), Some(_version)) = (words.next(), words.next()) else {
                    return Err(bad(line_number, "expected `format ENCODING 1.0`".into()));
                };
                encoding = Some(match name {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLe,
                    "binary_big_endian" => Encoding::BinaryBe,
                    other => {
                        return Err(bad(
                            line_number,
                            format!(
                                "unknown encoding `{other}`; expected ascii, \
                                 binary_little_endian or binary_big_endian"
                            ),
                        ))
                    }
                });
            }
            "obj_info" => {
                let key = words.next();
                let value = words.next().and_then(|v| v.parse::<usize>().ok());
                match key {
                    Some("num_cols") => grid_size.0 = value,
                    Some("num_rows") => grid_size.1 = value,
                    _ => {}
                }
            }
            "comment" | "" => {}
            "element" => {
                let (Some(name), Some(count), None) = (words.next(), words.next(), words.next())
                else {
                    return Err(bad(line_number, "expected `element NAME COUNT`".into()));
                };
                let Ok(count) = count.parse::<u64>() else {
                    return Err(bad(
                        line_number,
                        format!("the count `{count}` of element `{name}` is not a whole number"),
                    ));
                };
                if elements.iter().any(|e| e.name == name) {
                    return Err(bad(
                        line_number,
                        format!("element `{name}` is declared twice"),
                    ));
                }
                elements.push(Element {
                    name: name.to_owned(),
                    count,
                    properties: Vec::new(),
                });
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(bad(
                        line_number,
                        "a property comes before any element".into(),
                    ));
                };
                let words: Vec<&str> = words.collect();
                let (ty, name) = match words.as_slice() {
                    ["list", count, item, name] => {
                        let (Some(count), Some(item)) = (Scalar::parse(count), Scalar::parse(item))
                        else {
                            return Err(bad(line_number, "unknown type in list property".into()));
                        };
                        if !count.is_integer() {
                            return Err(bad(
                                line_number,
                                "a list's count type must be an integer type".into(),
                            ));
                        }
                        (PropertyType::List { count, item }, *name)
                    }
                    [ty, name] => {
                        let Some(ty) = Scalar::parse(ty) else {
                            return Err(bad(
                                line_number,
                                format!(
                                    "unknown property type `{ty}`; expected char, uchar, short, \
                                     ushort, int, uint, float, double or their sized names"
                                ),
                            ));
                        };
                        (PropertyType::Scalar(ty), *name)
                    }
                    _ => {
                        return Err(bad(
                            line_number,
                            "expected `property TYPE NAME` or `property list TYPE TYPE NAME`"
                                .into(),
                        ))
                    }
                };
                if element.property_index(name).is_some() {
                    return Err(bad(
                        line_number,
                        format!(
                            "property `{name}` of element `{}` is declared twice",
                            element.name
                        ),
                    ));
                }
                element.properties.push(Property {
                    name: name.to_owned(),
                    ty,
                });
            }
            "end_header" => break,
            other => {
                return Err(bad(
                    line_number,
                    format!(
                        "unknown header keyword `{other}`; expected format, comment, obj_info, \
                         element, property or end_header"
                    ),
                ))
            }
        }
    }
    let Some(encoding) = encoding else {
        return Err(bad(line_number, "the header has no `format` line".into()));
    };
    Ok(Header {
        encoding,
        elements,
        grid_size,
        body_start: offset,
        body_line: line_number + 1,
    })
}
