//! A bag read as a stream: one decoded message at a time, in log-time order, so that what is
//! held grows with what the caller keeps, not with the bag.
//!
//! A file with a summary and chunk indexes (what rosbag2 and `rosbags` write) is read through
//! the index ([`mcap::sans_io::IndexedReader`]): chunks of other topics are skipped and messages
//! come in log-time order, a chunk or two decompressed at a time. A file without an index (cut
//! short, or written without a summary) is read from start to end in file order
//! ([`mcap::io::MessageReader`]), and where it breaks the error names the last message read.
//! Definitions are checked as each channel is first met (for an indexed file: all of them when
//! the file is opened), and header stamps must not go backwards on a topic.

use super::cdr::{self, Value};
use super::msgdef::Definitions;
use super::{BagError, Message, TopicSpec, definitions_of, err, stamp_of};
use mcap::sans_io::{
    IndexedReadEvent, IndexedReader, IndexedReaderOptions, SummaryReadEvent, SummaryReader,
    SummaryReaderOptions,
};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// A message of one of the topics asked for, decoded.
#[derive(Clone, Debug)]
pub struct BagMessage {
    /// Its topic.
    pub topic: Arc<str>,
    /// Its message type, as the spec names it (`pkg/msg/Type`).
    pub msgtype: Arc<str>,
    /// The message.
    pub message: Message,
}

/// A channel of a topic asked for: its name, type and checked definitions.
#[derive(Debug)]
struct Checked {
    topic: Arc<str>,
    msgtype: Arc<str>,
    defs: Definitions,
}

/// Where the messages come from.
enum Source {
    /// Through the summary's chunk indexes, in log-time order.
    Indexed {
        file: File,
        reader: Box<IndexedReader>,
        channels: HashMap<u16, Arc<mcap::Channel<'static>>>,
        buf: Vec<u8>,
    },
    /// From start to end, in file order.
    Linear(Box<mcap::io::MessageReader<BufReader<File>>>),
}

/// What the reader keeps between messages: the channels met, and per topic the messages read
/// and the last header stamp.
#[derive(Debug, Default)]
struct State {
    channels: BTreeMap<u16, Option<Arc<Checked>>>,
    counts: BTreeMap<Arc<str>, usize>,
    last_stamp: BTreeMap<Arc<str>, i128>,
    /// The last message returned: `(topic, index)`.
    last: Option<(Arc<str>, usize)>,
    /// Every message met, of any topic.
    seen: u64,
}

/// A ROS 2 bag (one MCAP file) read message by message; see the module docs.
pub struct BagReader {
    path: PathBuf,
    specs: Vec<TopicSpec>,
    source: Source,
    state: State,
    summary_counts: Option<BTreeMap<String, u64>>,
    done: bool,
}

impl std::fmt::Debug for BagReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagReader")
            .field("path", &self.path)
            .field("indexed", &self.indexed())
            .field("read", &self.state.counts)
            .finish_non_exhaustive()
    }
}

/// The summary of `file`, when it has one that can be read.
fn summary_of(file: &mut File) -> Option<mcap::Summary> {
    let size = file.metadata().ok()?.len();
    let mut reader =
        SummaryReader::new_with_options(SummaryReaderOptions::default().with_file_size(size));
    while let Some(event) = reader.next_event() {
        match event.ok()? {
            SummaryReadEvent::ReadRequest(n) => {
                let read = file.read(reader.insert(n)).ok()?;
                reader.notify_read(read);
            }
            SummaryReadEvent::SeekRequest(to) => {
                let at = file.seek(to).ok()?;
                reader.notify_seeked(at);
            }
        }
    }
    reader.finish()
}

impl BagReader {
    /// Opens the MCAP file `path` to read the topics of `specs` (other topics are skipped).
    /// With an index, every channel of a topic asked for is checked now, and a channel of
    /// another type or definition is an error before any message is read.
    pub fn open(path: &Path, specs: &[TopicSpec]) -> Result<Self, BagError> {
        let shown = path.display();
        let mut file = File::open(path).map_err(|e| err(format!("`{shown}`: {e}")))?;
        let summary = summary_of(&mut file).filter(|s| !s.chunk_indexes.is_empty());
        let mut state = State::default();
        let (source, summary_counts) = match summary {
            Some(summary) => {
                let topics: Vec<String> = specs.iter().map(|s| s.topic.clone()).collect();
                let options = IndexedReaderOptions::new()
                    .with_order(mcap::sans_io::indexed_reader::ReadOrder::LogTime)
                    .include_topics(topics);
                let reader = IndexedReader::new_with_options(&summary, options)
                    .map_err(|e| err(format!("`{shown}`: its index cannot be read: {e}")))?;
                let mut ids: Vec<&u16> = summary.channels.keys().collect();
                ids.sort();
                for id in ids {
                    let channel = &summary.channels[id];
                    state.check_channel(channel, specs)?;
                }
                let counts = summary.stats.as_ref().map(|stats| {
                    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
                    for channel in summary.channels.values() {
                        let n = stats.channel_message_counts.get(&channel.id).copied();
                        *counts.entry(channel.topic.clone()).or_default() += n.unwrap_or(0);
                    }
                    counts
                });
                let source = Source::Indexed {
                    file,
                    reader: Box::new(reader),
                    channels: summary.channels.clone(),
                    buf: Vec::new(),
                };
                (source, counts)
            }
            None => {
                file.seek(SeekFrom::Start(0))
                    .map_err(|e| err(format!("`{shown}`: {e}")))?;
                let reader = mcap::io::MessageReader::new(BufReader::new(file));
                (Source::Linear(Box::new(reader)), None)
            }
        };
        Ok(Self {
            path: path.to_path_buf(),
            specs: specs.to_vec(),
            source,
            state,
            summary_counts,
            done: false,
        })
    }

    /// Whether the file is read through its index (in log-time order) rather than from start
    /// to end.
    pub fn indexed(&self) -> bool {
        matches!(self.source, Source::Indexed { .. })
    }

    /// Messages per topic as the file's summary counts them, when it has statistics.
    pub fn summary_counts(&self) -> Option<&BTreeMap<String, u64>> {
        self.summary_counts.as_ref()
    }

    /// Messages returned so far, per topic.
    pub fn counts(&self) -> &BTreeMap<Arc<str>, usize> {
        &self.state.counts
    }

    /// Messages met so far, of every topic read (with an index, the topics asked for only).
    pub fn seen(&self) -> u64 {
        self.state.seen
    }

    /// The next message of a topic asked for; `None` at the end; an error (after which there
    /// are no more messages) names the file and, where there is one, the topic and message.
    pub fn next_message(&mut self) -> Option<Result<BagMessage, BagError>> {
        if self.done {
            return None;
        }
        let out = self.next_inner();
        if !matches!(out, Some(Ok(_))) {
            self.done = true;
        }
        out
    }

    fn next_inner(&mut self) -> Option<Result<BagMessage, BagError>> {
        let shown = self.path.display().to_string();
        loop {
            match &mut self.source {
                Source::Indexed {
                    file,
                    reader,
                    channels,
                    buf,
                } => match reader.next_event()? {
                    Err(e) => return Some(Err(self.state.broken(&shown, &e.to_string()))),
                    Ok(IndexedReadEvent::ReadChunkRequest { offset, length }) => {
                        buf.resize(length, 0);
                        let read = file
                            .seek(SeekFrom::Start(offset))
                            .and_then(|_| file.read_exact(buf));
                        if let Err(e) = read {
                            return Some(Err(self.state.broken(&shown, &e.to_string())));
                        }
                        if let Err(e) = reader.insert_chunk_record_data(offset, buf) {
                            return Some(Err(self.state.broken(&shown, &e.to_string())));
                        }
                    }
                    Ok(IndexedReadEvent::Message { header, data }) => {
                        let Some(channel) = channels.get(&header.channel_id) else {
                            let e = format!(
                                "a message on channel {}, which the file does not define",
                                header.channel_id
                            );
                            return Some(Err(self.state.broken(&shown, &e)));
                        };
                        match self
                            .state
                            .take(&shown, channel, &self.specs, header.log_time, data)
                        {
                            Ok(Some(m)) => return Some(Ok(m)),
                            Ok(None) => {}
                            Err(e) => return Some(Err(e)),
                        }
                    }
                },
                Source::Linear(reader) => match reader.next()? {
                    Err(e) => return Some(Err(self.state.broken(&shown, &e.to_string()))),
                    Ok(m) => {
                        match self
                            .state
                            .take(&shown, &m.channel, &self.specs, m.log_time, &m.data)
                        {
                            Ok(Some(m)) => return Some(Ok(m)),
                            Ok(None) => {}
                            Err(e) => return Some(Err(e)),
                        }
                    }
                },
            }
        }
    }
}

impl Iterator for BagReader {
    type Item = Result<BagMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_message()
    }
}

impl State {
    /// Checks a channel of a topic asked for (once per channel); `None` for other topics.
    fn check_channel(
        &mut self,
        channel: &mcap::Channel<'_>,
        specs: &[TopicSpec],
    ) -> Result<Option<Arc<Checked>>, BagError> {
        if let Some(known) = self.channels.get(&channel.id) {
            return Ok(known.clone());
        }
        let checked = match specs.iter().find(|s| s.topic == channel.topic) {
            None => None,
            Some(spec) => {
                let (msgtype, defs) = definitions_of(channel, spec)?;
                Some(Arc::new(Checked {
                    topic: Arc::from(channel.topic.as_str()),
                    msgtype: Arc::from(msgtype.as_str()),
                    defs,
                }))
            }
        };
        self.channels.insert(channel.id, checked.clone());
        Ok(checked)
    }

    /// One message met: decoded and checked when its topic is asked for.
    fn take(
        &mut self,
        file: &str,
        channel: &mcap::Channel<'_>,
        specs: &[TopicSpec],
        log_time: u64,
        data: &[u8],
    ) -> Result<Option<BagMessage>, BagError> {
        self.seen += 1;
        let Some(checked) = self.check_channel(channel, specs)? else {
            return Ok(None);
        };
        let topic = &checked.topic;
        let index = self.counts.get(topic).copied().unwrap_or(0);
        let value: Value = cdr::decode(&checked.defs, data)
            .map_err(|e| err(format!("`{file}`: topic `{topic}`, message {index}: {e}")))?;
        let stamp = stamp_of(&value);
        if let Some(now) = stamp {
            if let Some(&before) = self.last_stamp.get(topic)
                && now < before
            {
                return Err(err(format!(
                    "`{file}`: topic `{topic}`, message {index}: its header stamp {:.3} s is \
                     before message {}'s {:.3} s (timestamps going backwards)",
                    now as f64 * 1e-9,
                    index.saturating_sub(1),
                    before as f64 * 1e-9
                )));
            }
            self.last_stamp.insert(topic.clone(), now);
        }
        self.counts.insert(topic.clone(), index + 1);
        self.last = Some((topic.clone(), index));
        Ok(Some(BagMessage {
            topic: topic.clone(),
            msgtype: checked.msgtype.clone(),
            message: Message {
                index,
                log_time,
                stamp,
                value,
            },
        }))
    }

    /// The error of a file that cannot be read on: cut short or malformed.
    fn broken(&self, file: &str, e: &str) -> BagError {
        if self.seen == 0 {
            err(format!(
                "`{file}` is not an MCAP file, or is truncated or malformed before its first \
                 message: {e}"
            ))
        } else {
            let last = self
                .last
                .as_ref()
                .map(|(topic, index)| format!(" (the last read: topic `{topic}`, message {index})"))
                .unwrap_or_default();
            err(format!(
                "`{file}` is truncated or malformed after {} messages{last}: {e}",
                self.seen
            ))
        }
    }
}
