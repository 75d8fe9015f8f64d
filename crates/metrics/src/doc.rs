//! A section's document as data: headings, paragraphs, tables, lists and code, whose text is
//! inline Markdown (`code`, **bold**, *italic*). Written out as Markdown here
//! ([`Doc::to_markdown`]) and rendered to HTML by the report's template, so that no page is made
//! by parsing Markdown back. [`Block::Markdown`] carries a document that exists only as Markdown
//! (an experiment's `.md` file), which the report still has to read as such.

use serde::{Deserialize, Serialize};

use crate::table::MdTable;

/// The key under which an output's JSON holds its document.
pub const DOCUMENT_KEY: &str = "document";

/// One block of a [`Doc`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "block", rename_all = "snake_case")]
pub enum Block {
    /// `#`-level heading (1 = the document's title).
    Heading {
        level: u8,
        text: String,
    },
    Paragraph {
        text: String,
    },
    Table {
        table: MdTable,
    },
    List {
        items: Vec<String>,
    },
    /// Preformatted text, shown as is.
    Code {
        text: String,
    },
    /// A whole document that exists only as Markdown.
    Markdown {
        text: String,
    },
}

/// A record serialised with its document after its own fields: what an output's JSON holds
/// (the key is [`DOCUMENT_KEY`]).
#[derive(Serialize)]
pub struct Documented<'a, T: Serialize> {
    #[serde(flatten)]
    pub record: &'a T,
    pub document: &'a Doc,
}

/// Blocks in reading order.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Doc {
    pub blocks: Vec<Block>,
}

impl Doc {
    pub fn new() -> Self {
        Self::default()
    }

    /// A document that exists only as Markdown text.
    pub fn from_markdown(text: impl Into<String>) -> Self {
        Self {
            blocks: vec![Block::Markdown { text: text.into() }],
        }
    }

    pub fn heading(&mut self, level: u8, text: impl Into<String>) -> &mut Self {
        self.push(Block::Heading {
            level,
            text: text.into(),
        })
    }

    pub fn paragraph(&mut self, text: impl Into<String>) -> &mut Self {
        self.push(Block::Paragraph { text: text.into() })
    }

    pub fn table(&mut self, table: MdTable) -> &mut Self {
        self.push(Block::Table { table })
    }

    pub fn list<S: Into<String>>(&mut self, items: impl IntoIterator<Item = S>) -> &mut Self {
        self.push(Block::List {
            items: items.into_iter().map(Into::into).collect(),
        })
    }

    pub fn code(&mut self, text: impl Into<String>) -> &mut Self {
        self.push(Block::Code { text: text.into() })
    }

    /// The paragraph that closes an output's document with the command that made it (nothing
    /// when it is not known): "Command: `…`".
    pub fn command(&mut self, command: Option<&str>) -> &mut Self {
        match command {
            Some(c) => self.paragraph(format!("Command: `{c}`")),
            None => self,
        }
    }

    pub fn push(&mut self, block: Block) -> &mut Self {
        self.blocks.push(block);
        self
    }

    /// The document as Markdown: blocks separated by one empty line, the text ending in a
    /// newline.
    pub fn to_markdown(&self) -> String {
        let parts: Vec<String> = self.blocks.iter().map(Block::to_markdown).collect();
        parts.join("\n")
    }
}

impl Block {
    /// This block as Markdown, ending in a newline.
    pub fn to_markdown(&self) -> String {
        match self {
            Block::Heading { level, text } => {
                format!("{} {text}\n", "#".repeat(usize::from((*level).clamp(1, 6))))
            }
            Block::Paragraph { text } => format!("{text}\n"),
            Block::Table { table } => table.to_markdown(),
            Block::List { items } => items.iter().map(|i| format!("- {i}\n")).collect(),
            Block::Code { text } => {
                let body = text.strip_suffix('\n').unwrap_or(text);
                format!("```\n{body}\n```\n")
            }
            Block::Markdown { text } if text.ends_with('\n') => text.clone(),
            Block::Markdown { text } => format!("{text}\n"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::table::Align;

    fn sample() -> Doc {
        let mut t = MdTable::new(&[("epoch", Align::Right), ("note", Align::Left)]);
        t.row(&["1", "`a|b`"]);
        let mut d = Doc::new();
        d.heading(2, "Run")
            .paragraph("`tiny` (RGB only), **4** epochs.")
            .table(t)
            .list(["one", "two"])
            .code("x < y\n");
        d
    }

    #[test]
    fn markdown_has_one_empty_line_between_blocks() {
        assert_eq!(
            sample().to_markdown(),
            "## Run\n\n`tiny` (RGB only), **4** epochs.\n\n| epoch | note |\n|---:|---|\n\
             | 1 | `a|b` |\n\n- one\n- two\n\n```\nx < y\n```\n"
        );
        assert_eq!(Doc::from_markdown("# T").to_markdown(), "# T\n");
        let mut d = Doc::new();
        d.paragraph("x")
            .command(Some("depthsense eval"))
            .command(None);
        assert_eq!(d.to_markdown(), "x\n\nCommand: `depthsense eval`\n");
    }

    #[test]
    fn a_record_keeps_its_fields_in_order_and_gains_the_document() {
        #[derive(Serialize)]
        struct R {
            z: u8,
            a: &'static str,
        }
        let d = Doc::from_markdown("x");
        let v = serde_json::to_string(&Documented {
            record: &R { z: 1, a: "b" },
            document: &d,
        })
        .unwrap();
        assert_eq!(
            v,
            format!(
                r#"{{"z":1,"a":"b","{DOCUMENT_KEY}":{{"blocks":[{{"block":"markdown","text":"x"}}]}}}}"#
            )
        );
    }

    #[test]
    fn a_document_survives_json() {
        let d = sample();
        let v = serde_json::to_value(&d).unwrap();
        assert_eq!(v["blocks"][0]["block"], "heading");
        assert_eq!(v["blocks"][2]["table"]["columns"][0][1], "right");
        let back: Doc = serde_json::from_value(v).unwrap();
        assert_eq!(back, d);
    }
}
