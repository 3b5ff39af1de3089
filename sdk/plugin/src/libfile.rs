//! Checks a plugin library *file* before the OS loader maps it.
//!
//! The dynamic loader maps a shared library's segments straight from the file; a truncated
//! file (an interrupted copy or build) then faults with `SIGBUS` inside `dlopen` when the
//! loader touches a page past the end of the file, which kills the host. So before `dlopen`
//! the host reads the file's headers and refuses, with an error naming the file:
//!
//! * anything that is not a regular file (after following symlinks), an empty file, or one of
//!   more than [`MAX_LIBRARY_BYTES`];
//! * on ELF platforms (Linux and the other Unixes but macOS): a file without the ELF magic, of
//!   another class (32/64-bit) or byte order than the host, not a shared object (`ET_DYN`), for
//!   another machine than the host (x86, x86-64, AArch64, ARM, RISC-V; other machines are not
//!   compared), whose header, program-header table or section-header table does not lie inside
//!   the file, whose table entries have another size than the ABI's, without a `PT_LOAD`
//!   segment, or with a segment (`PT_LOAD` and every other one with file contents:
//!   `p_offset + p_filesz`) or a section with file contents (`sh_offset + sh_size`, all but
//!   `SHT_NOBITS`) reaching past the end of the file;
//! * on macOS: a file that is neither a 64-bit Mach-O image of the host's byte order nor a
//!   universal ("fat") binary, whose load commands do not fit in the file, or with a segment
//!   (`LC_SEGMENT_64`: `fileoff + filesize`) or a fat slice (`offset + size`) past its end;
//! * on Windows: a file without the `MZ` and `PE\0\0` signatures, or whose section table or
//!   a section's raw data (`PointerToRawData + SizeOfRawData`) lies past the end of the file.
//!
//! The ELF, Mach-O and PE readers are plain functions over bytes and are tested on every
//! platform; only the choice of which one guards `dlopen` depends on the OS.
//!
//! What this does not cover: a file that is modified *after* the check (the loader maps it
//! later, and a file truncated while mapped faults on first access however it was checked),
//! and a file whose headers are consistent but whose code is garbage (that is the plugin's
//! code, which loading a plugin runs by design).

use std::fmt;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// The largest library file the host accepts (1 GiB). The shipped plugins are a few MB; a
/// plugin that bundles a network links it at run time rather than embedding it.
pub const MAX_LIBRARY_BYTES: u64 = 1 << 30;

/// What the file check found: the file's size and a one-line description of its format.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LibraryFile {
    /// Size in bytes.
    pub size: u64,
    /// For example `ELF 64-bit LSB shared object, x86-64: 10 program headers (4 PT_LOAD) and
    /// 30 section headers, all inside the file`.
    pub format: String,
}

/// Why the file was refused (the caller adds the path).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileProblem(pub String);

impl fmt::Display for FileProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

fn problem<T>(message: impl Into<String>) -> Result<T, FileProblem> {
    Err(FileProblem(message.into()))
}

/// Checks the file at `path` (see the module docs). The error is a sentence without the path.
pub fn check_library_file(path: &Path) -> Result<LibraryFile, FileProblem> {
    let meta = std::fs::metadata(path)
        .map_err(|e| FileProblem(format!("cannot read the file's metadata: {e}")))?;
    if !meta.is_file() {
        return problem("not a regular file");
    }
    let size = meta.len();
    if size == 0 {
        return problem("the file is empty");
    }
    if size > MAX_LIBRARY_BYTES {
        return problem(format!(
            "the file is {size} bytes, more than the {MAX_LIBRARY_BYTES}-byte limit for a plugin library"
        ));
    }
    let mut file =
        File::open(path).map_err(|e| FileProblem(format!("cannot open the file: {e}")))?;
    let format = if cfg!(any(target_os = "macos", target_os = "ios")) {
        check_macho(&mut file, size)?
    } else if cfg!(windows) {
        check_pe(&mut file, size)?
    } else {
        check_elf(&mut file, size)?
    };
    Ok(LibraryFile { size, format })
}

/// Reads `buf.len()` bytes at `offset`, or says that the file ends first.
fn read_at<R: Read + Seek>(
    r: &mut R,
    offset: u64,
    buf: &mut [u8],
    what: &str,
) -> Result<(), FileProblem> {
    r.seek(SeekFrom::Start(offset))
        .and_then(|_| r.read_exact(buf))
        .map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                FileProblem(format!(
                    "truncated: the file ends inside the {what} (bytes {offset}..{})",
                    offset + buf.len() as u64
                ))
            } else {
                FileProblem(format!("cannot read the {what}: {e}"))
            }
        })
}

/// `offset + len` when it is at most `size`, else a problem naming `what`.
fn within(
    offset: u64,
    len: u64,
    size: u64,
    what: impl FnOnce() -> String,
) -> Result<(), FileProblem> {
    match offset.checked_add(len) {
        Some(end) if end <= size => Ok(()),
        Some(end) => problem(format!(
            "truncated or corrupt: the {} ends at byte {end}, past the end of the file ({size} bytes)",
            what()
        )),
        None => problem(format!(
            "corrupt: the {} has offset {offset} and size {len}, which overflow",
            what()
        )),
    }
}

/// Little- or big-endian field reader over a header buffer.
#[derive(Clone, Copy)]
struct Fields {
    big: bool,
}

impl Fields {
    fn u16(self, b: &[u8], at: usize) -> u64 {
        let v = [b[at], b[at + 1]];
        u64::from(if self.big {
            u16::from_be_bytes(v)
        } else {
            u16::from_le_bytes(v)
        })
    }

    fn u32(self, b: &[u8], at: usize) -> u64 {
        let v = [b[at], b[at + 1], b[at + 2], b[at + 3]];
        u64::from(if self.big {
            u32::from_be_bytes(v)
        } else {
            u32::from_le_bytes(v)
        })
    }

    fn u64(self, b: &[u8], at: usize) -> u64 {
        let mut v = [0u8; 8];
        v.copy_from_slice(&b[at..at + 8]);
        if self.big {
            u64::from_be_bytes(v)
        } else {
            u64::from_le_bytes(v)
        }
    }
}

const ELF_MAGIC: [u8; 4] = [0x7f, b'E', b'L', b'F'];
const ET_DYN: u64 = 3;
const PT_NULL: u64 = 0;
const PT_LOAD: u64 = 1;
const SHT_NULL: u64 = 0;
const SHT_NOBITS: u64 = 8;
/// `e_phnum` value meaning "the count is in section 0's `sh_info`".
const PN_XNUM: u64 = 0xffff;

/// The ELF machine code of the host, where the check compares it.
fn host_machine() -> Option<(u64, &'static str)> {
    if cfg!(target_arch = "x86_64") {
        Some((62, "x86-64"))
    } else if cfg!(target_arch = "aarch64") {
        Some((183, "AArch64"))
    } else if cfg!(target_arch = "x86") {
        Some((3, "x86"))
    } else if cfg!(target_arch = "arm") {
        Some((40, "ARM"))
    } else if cfg!(any(target_arch = "riscv64", target_arch = "riscv32")) {
        Some((243, "RISC-V"))
    } else {
        None
    }
}

fn segment_name(p_type: u64) -> String {
    match p_type {
        1 => "PT_LOAD".into(),
        2 => "PT_DYNAMIC".into(),
        3 => "PT_INTERP".into(),
        4 => "PT_NOTE".into(),
        6 => "PT_PHDR".into(),
        7 => "PT_TLS".into(),
        0x6474_e550 => "PT_GNU_EH_FRAME".into(),
        0x6474_e552 => "PT_GNU_RELRO".into(),
        other => format!("type {other:#x}"),
    }
}

/// The ELF checks of the module docs, for a file of `size` bytes.
pub fn check_elf<R: Read + Seek>(r: &mut R, size: u64) -> Result<String, FileProblem> {
    let mut ident = [0u8; 16];
    if size < 16 {
        return problem(format!(
            "not an ELF shared library: the file has only {size} bytes"
        ));
    }
    read_at(r, 0, &mut ident, "ELF identification")?;
    if ident[..4] != ELF_MAGIC {
        return problem(format!(
            "not an ELF shared library (the file starts with {:02x} {:02x} {:02x} {:02x}, not 7f 45 4c 46)",
            ident[0], ident[1], ident[2], ident[3]
        ));
    }
    let wide = match ident[4] {
        1 => false,
        2 => true,
        c => return problem(format!("corrupt ELF header: unknown class {c}")),
    };
    let big = match ident[5] {
        1 => false,
        2 => true,
        d => return problem(format!("corrupt ELF header: unknown byte order {d}")),
    };
    let host_wide = cfg!(target_pointer_width = "64");
    if wide != host_wide {
        return problem(format!(
            "a {}-bit ELF file, but this host is {}-bit",
            if wide { 64 } else { 32 },
            if host_wide { 64 } else { 32 }
        ));
    }
    let host_big = cfg!(target_endian = "big");
    if big != host_big {
        let order = |b: bool| if b { "big-endian" } else { "little-endian" };
        return problem(format!(
            "a {} ELF file, but this host is {}",
            order(big),
            order(host_big)
        ));
    }
    if ident[6] != 1 {
        return problem(format!("corrupt ELF header: version {}", ident[6]));
    }
    check_elf_layout(r, size, wide, big)
}

/// Everything after the identification bytes (class and byte order given): the header, then
/// the section headers (which may hold the real counts), the program headers and every
/// segment, then every section.
fn check_elf_layout<R: Read + Seek>(
    r: &mut R,
    size: u64,
    wide: bool,
    big: bool,
) -> Result<String, FileProblem> {
    let f = Fields { big };
    let mut h = ElfHeader::read(r, size, f, wide)?;
    h.check_kind()?;
    let sh_size: u64 = if wide { 64 } else { 40 };
    let sections = read_section_headers(r, size, f, &mut h)?;
    let (phnum, loads) = check_segments(r, size, f, &h)?;
    for (i, sh) in sections.chunks_exact(sh_size as usize).enumerate() {
        let sh_type = f.u32(sh, 4);
        if sh_type == SHT_NULL || sh_type == SHT_NOBITS {
            continue;
        }
        let (offset, len) = if wide {
            (f.u64(sh, 24), f.u64(sh, 32))
        } else {
            (f.u32(sh, 16), f.u32(sh, 20))
        };
        within(offset, len, size, || format!("section {i}"))?;
    }
    let e_machine = h.e_machine;
    let machine = host_machine().map_or_else(|| format!("machine {e_machine}"), |m| m.1.into());
    Ok(format!(
        "ELF {}-bit {} shared object, {machine}: {phnum} program headers ({loads} PT_LOAD) and \
         {} section headers, all inside the file",
        if wide { 64 } else { 32 },
        if big { "MSB" } else { "LSB" },
        sections.len() as u64 / sh_size
    ))
}

/// The fields of an ELF header the checks use.
#[derive(Clone, Copy, Debug)]
struct ElfHeader {
    wide: bool,
    /// The header's size for this class (52 or 64 bytes).
    ehsize: usize,
    e_type: u64,
    e_machine: u64,
    e_ehsize: u64,
    phoff: u64,
    shoff: u64,
    phentsize: u64,
    phnum: u64,
    shentsize: u64,
    shnum: u64,
}

impl ElfHeader {
    fn read<R: Read + Seek>(
        r: &mut R,
        size: u64,
        f: Fields,
        wide: bool,
    ) -> Result<Self, FileProblem> {
        let ehsize: usize = if wide { 64 } else { 52 };
        let mut h = vec![0u8; ehsize];
        within(0, ehsize as u64, size, || "ELF header".into())?;
        read_at(r, 0, &mut h, "ELF header")?;
        let word = |at32: usize, at64: usize| {
            if wide {
                f.u64(&h, at64)
            } else {
                f.u32(&h, at32)
            }
        };
        let base = if wide { 52 } else { 40 };
        Ok(Self {
            wide,
            ehsize,
            e_type: f.u16(&h, 16),
            e_machine: f.u16(&h, 18),
            phoff: word(28, 32),
            shoff: word(32, 40),
            e_ehsize: f.u16(&h, base),
            phentsize: f.u16(&h, base + 2),
            phnum: f.u16(&h, base + 4),
            shentsize: f.u16(&h, base + 6),
            shnum: f.u16(&h, base + 8),
        })
    }

    /// A shared library for this host's machine, with a header of its class's size.
    fn check_kind(&self) -> Result<(), FileProblem> {
        if self.e_type != ET_DYN {
            let what = match self.e_type {
                1 => "a relocatable object (.o)".to_owned(),
                2 => "an executable".to_owned(),
                4 => "a core dump".to_owned(),
                t => format!("an ELF file of type {t}"),
            };
            return problem(format!("{what}, not a shared library"));
        }
        let e_machine = self.e_machine;
        if let Some((code, name)) = host_machine() {
            if e_machine != code {
                return problem(format!(
                    "built for ELF machine {e_machine}, but this host is {name} (machine {code})"
                ));
            }
        }
        let (e_ehsize, ehsize) = (self.e_ehsize, self.ehsize);
        if e_ehsize < ehsize as u64 {
            return problem(format!(
                "corrupt ELF header: e_ehsize is {e_ehsize}, the header is {ehsize} bytes"
            ));
        }
        Ok(())
    }
}

/// The section-header table (empty when the file has none), checked to lie inside the file.
/// Section 0 may hold the real section and program-header counts (extended numbering); they
/// are written into `h`.
fn read_section_headers<R: Read + Seek>(
    r: &mut R,
    size: u64,
    f: Fields,
    h: &mut ElfHeader,
) -> Result<Vec<u8>, FileProblem> {
    let wide = h.wide;
    let sh_size: u64 = if wide { 64 } else { 40 };
    let (shoff, shentsize) = (h.shoff, h.shentsize);
    if shoff == 0 {
        return Ok(Vec::new());
    }
    if shentsize != sh_size {
        return problem(format!(
            "corrupt ELF header: section headers are {shentsize} bytes, expected {sh_size}"
        ));
    }
    within(shoff, sh_size, size, || "section-header table".into())?;
    let mut s0 = vec![0u8; sh_size as usize];
    read_at(r, shoff, &mut s0, "section-header table")?;
    if h.shnum == 0 {
        h.shnum = if wide { f.u64(&s0, 32) } else { f.u32(&s0, 20) };
    }
    if h.phnum == PN_XNUM {
        h.phnum = f.u32(&s0, if wide { 44 } else { 28 });
    }
    let shnum = h.shnum;
    // The extended count can be any 32/64-bit number; more than a million sections is not
    // a library this host loads (and the table must fit in the file anyway).
    if shnum > 1 << 20 {
        return problem(format!("corrupt ELF header: {shnum} sections"));
    }
    within(shoff, shnum * sh_size, size, || {
        format!("section-header table ({shnum} entries)")
    })?;
    let mut table = vec![0u8; (shnum * sh_size) as usize];
    read_at(r, shoff, &mut table, "section-header table")?;
    Ok(table)
}

/// The program-header table and every segment with file contents lie inside the file, and
/// there is a `PT_LOAD` segment. Returns the number of program headers and of `PT_LOAD`s.
fn check_segments<R: Read + Seek>(
    r: &mut R,
    size: u64,
    f: Fields,
    h: &ElfHeader,
) -> Result<(u64, usize), FileProblem> {
    let wide = h.wide;
    let ph_size: u64 = if wide { 56 } else { 32 };
    let (phoff, phentsize, phnum) = (h.phoff, h.phentsize, h.phnum);
    if phnum == 0 {
        return problem("corrupt ELF file: a shared library without program headers");
    }
    if phentsize != ph_size {
        return problem(format!(
            "corrupt ELF header: program headers are {phentsize} bytes, expected {ph_size}"
        ));
    }
    within(phoff, phnum * ph_size, size, || {
        format!("program-header table ({phnum} entries)")
    })?;
    let mut table = vec![0u8; (phnum * ph_size) as usize];
    read_at(r, phoff, &mut table, "program-header table")?;
    let mut loads = 0;
    for (i, ph) in table.chunks_exact(ph_size as usize).enumerate() {
        let p_type = f.u32(ph, 0);
        let (offset, filesz) = if wide {
            (f.u64(ph, 8), f.u64(ph, 32))
        } else {
            (f.u32(ph, 4), f.u32(ph, 16))
        };
        if p_type == PT_LOAD {
            loads += 1;
        }
        if p_type == PT_NULL || filesz == 0 {
            continue;
        }
        within(offset, filesz, size, || {
            format!("{} segment {i}", segment_name(p_type))
        })?;
    }
    if loads == 0 {
        return problem("corrupt ELF file: no PT_LOAD segment");
    }
    Ok((phnum, loads))
}

const MH_MAGIC_64: u32 = 0xfeed_facf;
const FAT_MAGIC: u32 = 0xcafe_babe;
const LC_SEGMENT_64: u64 = 0x19;

/// The Mach-O checks of the module docs.
pub fn check_macho<R: Read + Seek>(r: &mut R, size: u64) -> Result<String, FileProblem> {
    let mut magic = [0u8; 4];
    if size < 4 {
        return problem("not a Mach-O library: the file is shorter than its magic number");
    }
    read_at(r, 0, &mut magic, "Mach-O magic")?;
    let host_big = cfg!(target_endian = "big");
    let native = if host_big {
        u32::from_be_bytes(magic)
    } else {
        u32::from_le_bytes(magic)
    };
    if u32::from_be_bytes(magic) == FAT_MAGIC {
        // Universal binary: big-endian header, then `nfat_arch` 20-byte slices.
        let mut h = [0u8; 8];
        read_at(r, 0, &mut h, "universal-binary header")?;
        let f = Fields { big: true };
        let n = f.u32(&h, 4);
        if n == 0 || n > 64 {
            return problem(format!("corrupt universal binary: {n} architectures"));
        }
        within(8, n * 20, size, || "universal-binary slice table".into())?;
        let mut t = vec![0u8; (n * 20) as usize];
        read_at(r, 8, &mut t, "universal-binary slice table")?;
        for (i, a) in t.chunks_exact(20).enumerate() {
            within(f.u32(a, 8), f.u32(a, 12), size, || {
                format!("universal-binary slice {i}")
            })?;
        }
        return Ok(format!(
            "Mach-O universal binary, {n} slices inside the file"
        ));
    }
    if native != MH_MAGIC_64 {
        return problem(format!(
            "not a 64-bit Mach-O library of this host's byte order (magic {:02x}{:02x}{:02x}{:02x})",
            magic[0], magic[1], magic[2], magic[3]
        ));
    }
    let f = Fields { big: host_big };
    let mut h = [0u8; 32];
    within(0, 32, size, || "Mach-O header".into())?;
    read_at(r, 0, &mut h, "Mach-O header")?;
    let (ncmds, sizeofcmds) = (f.u32(&h, 16), f.u32(&h, 20));
    within(32, sizeofcmds, size, || "load commands".into())?;
    let mut cmds = vec![0u8; sizeofcmds as usize];
    read_at(r, 32, &mut cmds, "load commands")?;
    let mut at = 0usize;
    let mut segments = 0;
    for i in 0..ncmds {
        if at + 8 > cmds.len() {
            return problem(format!(
                "corrupt Mach-O file: load command {i} lies past `sizeofcmds`"
            ));
        }
        let (cmd, cmdsize) = (f.u32(&cmds, at), f.u32(&cmds, at + 4) as usize);
        if cmdsize < 8 || at + cmdsize > cmds.len() {
            return problem(format!(
                "corrupt Mach-O file: load command {i} has size {cmdsize}"
            ));
        }
        if cmd == LC_SEGMENT_64 {
            if cmdsize < 72 {
                return problem(format!("corrupt Mach-O file: segment command {i} is short"));
            }
            segments += 1;
            within(f.u64(&cmds, at + 40), f.u64(&cmds, at + 48), size, || {
                format!("segment of load command {i}")
            })?;
        }
        at += cmdsize;
    }
    Ok(format!(
        "Mach-O 64-bit image: {ncmds} load commands ({segments} segments), all inside the file"
    ))
}

/// The PE checks of the module docs.
pub fn check_pe<R: Read + Seek>(r: &mut R, size: u64) -> Result<String, FileProblem> {
    let f = Fields { big: false };
    let mut dos = [0u8; 64];
    if size < 64 {
        return problem("not a PE library: the file is shorter than a DOS header");
    }
    read_at(r, 0, &mut dos, "DOS header")?;
    if &dos[..2] != b"MZ" {
        return problem("not a PE library: no `MZ` signature");
    }
    let pe = f.u32(&dos, 0x3c);
    within(pe, 24, size, || "PE header".into())?;
    let mut coff = [0u8; 24];
    read_at(r, pe, &mut coff, "PE header")?;
    if &coff[..4] != b"PE\0\0" {
        return problem("not a PE library: no `PE` signature");
    }
    let sections = f.u16(&coff, 6);
    let optional = f.u16(&coff, 20);
    let table = pe + 24 + optional;
    within(table, sections * 40, size, || "section table".into())?;
    let mut t = vec![0u8; (sections * 40) as usize];
    read_at(r, table, &mut t, "section table")?;
    for (i, s) in t.chunks_exact(40).enumerate() {
        within(f.u32(s, 20), f.u32(s, 16), size, || format!("section {i}"))?;
    }
    Ok(format!(
        "PE image: {sections} sections, all inside the file"
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    /// A minimal 64-bit little-endian ELF shared object for x86-64: header, two program
    /// headers (one PT_LOAD over the first `load` bytes), `payload` bytes, then a section
    /// table with a null section and one PROGBITS section over the payload.
    fn elf(load: u64, payload: usize) -> Vec<u8> {
        let mut b = vec![0u8; 64];
        b[..4].copy_from_slice(&ELF_MAGIC);
        b[4] = 2; // 64-bit
        b[5] = 1; // little-endian
        b[6] = 1;
        let put16 =
            |b: &mut Vec<u8>, at: usize, v: u16| b[at..at + 2].copy_from_slice(&v.to_le_bytes());
        let put32 =
            |b: &mut Vec<u8>, at: usize, v: u32| b[at..at + 4].copy_from_slice(&v.to_le_bytes());
        let put64 =
            |b: &mut Vec<u8>, at: usize, v: u64| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
        put16(&mut b, 16, ET_DYN as u16);
        put16(&mut b, 18, host_machine().map_or(0, |m| m.0) as u16);
        put32(&mut b, 20, 1);
        put64(&mut b, 32, 64); // phoff
        put16(&mut b, 52, 64); // ehsize
        put16(&mut b, 54, 56); // phentsize
        put16(&mut b, 56, 2); // phnum
        put16(&mut b, 58, 64); // shentsize
        put16(&mut b, 60, 2); // shnum
        let mut ph = vec![0u8; 112];
        put32(&mut ph, 0, PT_LOAD as u32);
        put64(&mut ph, 8, 0);
        put64(&mut ph, 32, load);
        put32(&mut ph, 56, 0x6474_e551); // PT_GNU_STACK, no file contents
        b.extend_from_slice(&ph);
        let payload_at = b.len() as u64;
        b.extend(std::iter::repeat_n(0xabu8, payload));
        let shoff = b.len() as u64;
        put64(&mut b, 40, shoff);
        let mut sh = vec![0u8; 128];
        put32(&mut sh, 64 + 4, 1); // PROGBITS
        put64(&mut sh, 64 + 24, payload_at);
        put64(&mut sh, 64 + 32, payload as u64);
        b.extend_from_slice(&sh);
        b
    }

    fn check(bytes: &[u8]) -> Result<String, FileProblem> {
        check_elf(&mut Cursor::new(bytes), bytes.len() as u64)
    }

    #[test]
    fn a_consistent_elf_file_passes() {
        if !cfg!(all(target_pointer_width = "64", target_endian = "little")) {
            return;
        }
        let b = elf(64 + 112 + 100, 100);
        let format = check(&b).expect("valid");
        assert!(format.contains("2 program headers (1 PT_LOAD)"), "{format}");
        assert!(format.contains("2 section headers"), "{format}");
    }

    #[test]
    fn truncated_elf_files_are_refused_naming_what_is_cut() {
        if !cfg!(all(target_pointer_width = "64", target_endian = "little")) {
            return;
        }
        let b = elf(64 + 112 + 100, 100);
        // Half the file: the section-header table is gone.
        let half = &b[..b.len() / 2];
        let err = check(half).expect_err("truncated");
        assert!(err.0.contains("section-header table"), "{err}");
        assert!(err.0.contains("past the end of the file"), "{err}");
        // A PT_LOAD segment longer than the file.
        let long = elf(1 << 20, 100);
        let err = check(&long).expect_err("segment past the end");
        assert!(err.0.contains("PT_LOAD segment 0"), "{err}");
        // Cut inside the header.
        let err = check(&b[..40]).expect_err("header cut");
        assert!(err.0.contains("ELF header"), "{err}");
        // Overflowing offsets are refused, not wrapped.
        let mut wrap = elf(100, 100);
        wrap[64 + 8..64 + 16].copy_from_slice(&u64::MAX.to_le_bytes());
        let err = check(&wrap).expect_err("overflow");
        assert!(err.0.contains("overflow"), "{err}");
    }

    #[test]
    fn other_elf_files_are_refused() {
        if !cfg!(all(target_pointer_width = "64", target_endian = "little")) {
            return;
        }
        let good = elf(64 + 112 + 100, 100);
        let mut exe = good.clone();
        exe[16] = 2;
        assert!(check(&exe).expect_err("exe").0.contains("an executable"));
        let mut narrow = good.clone();
        narrow[4] = 1;
        assert!(
            check(&narrow)
                .expect_err("32-bit")
                .0
                .contains("32-bit ELF file")
        );
        let mut big = good.clone();
        big[5] = 2;
        assert!(check(&big).expect_err("BE").0.contains("big-endian"));
        if host_machine().is_some() {
            let mut other = good.clone();
            other[18] = 0x99;
            assert!(
                check(&other)
                    .expect_err("machine")
                    .0
                    .contains("built for ELF machine")
            );
        }
        let mut phent = good.clone();
        phent[54] = 55;
        assert!(
            check(&phent)
                .expect_err("phentsize")
                .0
                .contains("program headers are 55 bytes")
        );
        let err = check(b"name = \"not a plugin\"\n").expect_err("text");
        assert!(err.0.starts_with("not an ELF shared library"), "{err}");
    }

    #[test]
    fn mach_o_and_pe_readers_check_their_tables() {
        // Mach-O: header + one LC_SEGMENT_64 (72 bytes) covering `filesize` bytes.
        let macho = |filesize: u64| {
            let mut b = vec![0u8; 32 + 72];
            let native32 = |v: u32| {
                if cfg!(target_endian = "big") {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                }
            };
            let native64 = |v: u64| {
                if cfg!(target_endian = "big") {
                    v.to_be_bytes()
                } else {
                    v.to_le_bytes()
                }
            };
            b[..4].copy_from_slice(&native32(MH_MAGIC_64));
            b[16..20].copy_from_slice(&native32(1));
            b[20..24].copy_from_slice(&native32(72));
            b[32..36].copy_from_slice(&native32(LC_SEGMENT_64 as u32));
            b[36..40].copy_from_slice(&native32(72));
            b[32 + 48..32 + 56].copy_from_slice(&native64(filesize));
            b
        };
        let ok = macho(104);
        assert!(check_macho(&mut Cursor::new(&ok), ok.len() as u64).is_ok());
        let bad = macho(4096);
        let err = check_macho(&mut Cursor::new(&bad), bad.len() as u64).expect_err("segment");
        assert!(err.0.contains("past the end"), "{err}");
        let err = check_macho(&mut Cursor::new(b"abcdefgh"), 8).expect_err("magic");
        assert!(err.0.contains("not a 64-bit Mach-O"), "{err}");

        // PE: DOS header, PE header at 64 without optional header, one section.
        let pe = |raw_size: u32| {
            let mut b = vec![0u8; 64 + 24 + 40];
            b[..2].copy_from_slice(b"MZ");
            b[0x3c..0x40].copy_from_slice(&64u32.to_le_bytes());
            b[64..68].copy_from_slice(b"PE\0\0");
            b[64 + 6..64 + 8].copy_from_slice(&1u16.to_le_bytes());
            b[88 + 16..88 + 20].copy_from_slice(&raw_size.to_le_bytes());
            b[88 + 20..88 + 24].copy_from_slice(&64u32.to_le_bytes());
            b
        };
        let ok = pe(64);
        assert!(check_pe(&mut Cursor::new(&ok), ok.len() as u64).is_ok());
        let bad = pe(1 << 20);
        let err = check_pe(&mut Cursor::new(&bad), bad.len() as u64).expect_err("section");
        assert!(err.0.contains("section 0"), "{err}");
    }
}
