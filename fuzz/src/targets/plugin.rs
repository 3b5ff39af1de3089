//! The plugin boundary: library files before `dlopen` (ELF, Mach-O, PE headers) and the tables
//! a plugin hands the host (entry table, factory array, vtables, strings), built in memory from
//! the input and run through the host's own validation.
//!
//! Tables are built so that they keep the validation's documented contract (whatever a pointer
//! claims is readable is readable): a string is null, points into the input with a length
//! inside it, or claims more than any cap (refused before it is read); a factory array holds
//! the factories its count and stride describe whenever both are within the caps.

use crate::{Scratch, Target};
use human2nav_plugin::PluginKind;
use human2nav_plugin::abi::{
    ABI_VERSION, H2nBuffer, H2nConstraintVTable, H2nCreateArgs, H2nEmbodimentVTable, H2nFactory,
    H2nObject, H2nPlannerVTable, H2nPluginEntry, H2nStatus, H2nStr,
};
use human2nav_plugin::host::fuzzing;
use human2nav_plugin::libfile::{check_elf, check_library_file, check_macho, check_pe};
use human2nav_plugin::validate::{MAX_DESCRIPTION_BYTES, MAX_FACTORIES, MAX_TABLE_BYTES};
use std::ffi::c_void;
use std::io::Cursor;

pub(crate) fn targets() -> Vec<Target> {
    vec![
        Target {
            name: "plugin_file",
            covers: "library headers before dlopen: libfile::check_elf / check_macho / check_pe \
                     on mutated and truncated images, and check_library_file on a temp file",
            seeds: file_seeds,
            exec: plugin_file,
        },
        Target {
            name: "plugin_entry",
            covers: "entry tables, factory arrays and their strings through the host's \
                     from_entry validation (ABI version, sizes, counts, strides, caps, UTF-8, \
                     null slots, duplicate factories)",
            seeds: || vec![vec![0u8; 64], (0u8..=255).collect()],
            exec: plugin_entry,
        },
        Target {
            name: "plugin_vtable",
            covers: "constraint, embodiment and planner vtables (sizes, null required slots, \
                     alignment) through the host's checked_vtable",
            seeds: || vec![vec![0u8; 96], vec![0xff; 96]],
            exec: plugin_vtable,
        },
    ]
}

/// Reads the input as a stream of numbers; past its end, zeros.
struct Bytes<'a> {
    b: &'a [u8],
    i: usize,
}

impl Bytes<'_> {
    fn u8(&mut self) -> u8 {
        let v = self.b.get(self.i).copied().unwrap_or(0);
        self.i += 1;
        v
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }
    fn u64(&mut self) -> u64 {
        u64::from(self.u32()) | (u64::from(self.u32()) << 32)
    }
}

unsafe extern "C" fn create_nothing(
    _: *const H2nCreateArgs,
    _: *mut H2nObject,
    _: *mut H2nBuffer,
) -> H2nStatus {
    -1
}

/// A string field: empty, null with a length, inside `text`, or claiming more than any cap.
fn string(r: &mut Bytes<'_>, text: &[u8]) -> H2nStr {
    match r.u8() % 6 {
        0 => H2nStr::EMPTY,
        1 => H2nStr {
            ptr: std::ptr::null(),
            len: (r.u64() as usize).max(1),
        },
        2 | 3 if !text.is_empty() => {
            let at = usize::from(r.u8()) % text.len();
            let len = usize::from(r.u8()) % (text.len() - at + 1);
            H2nStr {
                ptr: text[at..].as_ptr(),
                len,
            }
        }
        4 => H2nStr {
            ptr: text.as_ptr(),
            len: MAX_DESCRIPTION_BYTES + 1 + (r.u64() as usize) % (usize::MAX / 2),
        },
        _ => H2nStr::new(if r.u8() % 2 == 0 { "fixture" } else { "é" }),
    }
}

/// A size field: usually the right one, else an edge or a random value.
fn size_field(r: &mut Bytes<'_>, right: usize) -> u32 {
    match r.u8() % 10 {
        0..=5 => right as u32,
        6 => *[
            0u32,
            4,
            8,
            right as u32 - 1,
            right as u32 + 1,
            right as u32 + 8,
            MAX_TABLE_BYTES as u32,
            MAX_TABLE_BYTES as u32 + 1,
            u32::MAX,
        ]
        .get(usize::from(r.u8()) % 9)
        .unwrap_or(&0),
        7 => (right as u32 + 8 * u32::from(r.u8())).min(MAX_TABLE_BYTES as u32),
        _ => r.u32(),
    }
}

/// An 8-byte-aligned zeroed buffer of at least `bytes` bytes.
fn words(bytes: usize) -> Vec<u64> {
    vec![0u64; bytes.div_ceil(8) + 1]
}

fn plugin_entry(_: &Scratch, input: &[u8]) {
    let split = input.len().min(48);
    let (head, text) = input.split_at(split);
    let mut r = Bytes { b: head, i: 0 };
    let abi_version = if r.u8() % 8 == 0 {
        r.u32()
    } else {
        ABI_VERSION
    };
    let struct_size = size_field(&mut r, std::mem::size_of::<H2nPluginEntry>());
    let name = string(&mut r, text);
    let version = string(&mut r, text);
    let fsize = std::mem::size_of::<H2nFactory>();
    let count = match r.u8() % 8 {
        0 => 0,
        1 => MAX_FACTORIES + (r.u64() as usize) % (usize::MAX - MAX_FACTORIES),
        2 => usize::from(r.u8()) % (MAX_FACTORIES + 2),
        _ => usize::from(r.u8() % 5),
    };
    let stride = size_field(&mut r, fsize);
    // The factory array: `count` factories `stride` apart when both are within the caps.
    let usable = count <= MAX_FACTORIES && (stride as usize) <= MAX_TABLE_BYTES;
    let mut array = words(if usable {
        count * (stride as usize).max(fsize) + 8
    } else {
        8
    });
    let base = array.as_mut_ptr().cast::<u8>();
    // SAFETY: the buffer holds at least 8 bytes; factory 0's size is its first u32.
    unsafe { base.cast::<u32>().write(stride) };
    if usable && stride as usize >= fsize && stride % 8 == 0 {
        for i in 0..count {
            let mut f_size = stride;
            if r.u8() % 16 == 0 {
                f_size = r.u32();
            }
            let kind = [1u32, 2, 3, 0, 99][usize::from(r.u8()) % 5];
            let f = H2nFactory {
                struct_size: if i == 0 { stride } else { f_size },
                kind,
                name: string(&mut r, text),
                description: string(&mut r, text),
                create: if r.u8() % 8 == 0 {
                    None
                } else {
                    Some(create_nothing)
                },
            };
            // SAFETY: `i * stride + stride` bytes lie inside the buffer (sized above), and the
            // stride is a multiple of the factory's alignment.
            unsafe { base.add(i * stride as usize).cast::<H2nFactory>().write(f) };
        }
    }
    let factories = match r.u8() % 16 {
        0 => std::ptr::null(),
        // SAFETY: one byte into the buffer (misaligned on purpose; refused before reading).
        1 => unsafe { base.add(1).cast::<H2nFactory>() },
        _ => base.cast::<H2nFactory>(),
    };
    let mut table = words(MAX_TABLE_BYTES);
    let entry = H2nPluginEntry {
        abi_version,
        struct_size,
        name,
        version,
        factories,
        factory_count: count,
        find_factory: None,
    };
    let tp = table.as_mut_ptr().cast::<H2nPluginEntry>();
    // SAFETY: the buffer is 4 KiB + 8 bytes, 8-byte aligned.
    unsafe { tp.write(entry) };
    let raw = match r.u8() % 16 {
        0 => std::ptr::null(),
        // SAFETY: inside the buffer.
        1 => unsafe { tp.cast::<u8>().add(4).cast::<H2nPluginEntry>() },
        _ => tp.cast_const(),
    };
    // SAFETY: built above to the validation's contract (module docs); `table`, `array` and
    // `input` outlive the call.
    let (r, checks) = unsafe { fuzzing::check_entry_table(raw) };
    if let Ok(fs) = r {
        assert!(fs.len() <= MAX_FACTORIES);
    }
    for c in checks {
        let _ = c.to_string();
    }
}

fn plugin_vtable(_: &Scratch, input: &[u8]) {
    let mut r = Bytes { b: input, i: 0 };
    let (kind, right) = match r.u8() % 4 {
        0 => (
            PluginKind::Constraint,
            std::mem::size_of::<H2nConstraintVTable>(),
        ),
        1 => (
            PluginKind::Embodiment,
            std::mem::size_of::<H2nEmbodimentVTable>(),
        ),
        2 => (PluginKind::Planner, std::mem::size_of::<H2nPlannerVTable>()),
        _ => (PluginKind::Unknown(u32::from(r.u8())), 64),
    };
    let size = size_field(&mut r, right);
    let mut table = words(MAX_TABLE_BYTES);
    // Function slots: each null or a non-null value (never called by the validation).
    for w in table.iter_mut().take(16).skip(1) {
        *w = if r.u8() % 5 == 0 { 0 } else { 0x1000 };
    }
    let tp = table.as_mut_ptr();
    // SAFETY: 8-byte aligned buffer; the size is the first u32.
    unsafe { tp.cast::<u32>().write(size) };
    let raw: *const c_void = match r.u8() % 16 {
        0 => std::ptr::null(),
        // SAFETY: inside the buffer.
        1 => unsafe { tp.cast::<u8>().add(4).cast::<c_void>() },
        _ => tp.cast::<c_void>(),
    };
    // SAFETY: a 4 KiB + 8-byte buffer, so whatever size is accepted is readable.
    let _ = unsafe { fuzzing::check_vtable(kind, raw) };
    let text = &input[input.len().min(8)..];
    let s = string(&mut r, text);
    // SAFETY: `string` keeps the contract (inside `input`, null, or over the cap).
    let _ = unsafe { fuzzing::read_plugin_str(s, MAX_DESCRIPTION_BYTES) };
}

/// A minimal ELF shared object for the host's class, byte order and machine; a Mach-O image
/// with one segment; a PE image with one section.
fn file_seeds() -> Vec<Vec<u8>> {
    let machine: u16 = if cfg!(target_arch = "aarch64") {
        183
    } else if cfg!(target_arch = "x86") {
        3
    } else {
        62
    };
    let mut elf = vec![0u8; 64];
    elf[..4].copy_from_slice(b"\x7fELF");
    elf[4] = if cfg!(target_pointer_width = "64") {
        2
    } else {
        1
    };
    elf[5] = if cfg!(target_endian = "big") { 2 } else { 1 };
    elf[6] = 1;
    let put16 =
        |b: &mut Vec<u8>, at: usize, v: u16| b[at..at + 2].copy_from_slice(&v.to_le_bytes());
    let put32 =
        |b: &mut Vec<u8>, at: usize, v: u32| b[at..at + 4].copy_from_slice(&v.to_le_bytes());
    let put64 =
        |b: &mut Vec<u8>, at: usize, v: u64| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
    put16(&mut elf, 16, 3); // ET_DYN
    put16(&mut elf, 18, machine);
    put32(&mut elf, 20, 1);
    put64(&mut elf, 32, 64);
    put16(&mut elf, 52, 64);
    put16(&mut elf, 54, 56);
    put16(&mut elf, 56, 2);
    put16(&mut elf, 58, 64);
    put16(&mut elf, 60, 2);
    let mut ph = vec![0u8; 112];
    put32(&mut ph, 0, 1); // PT_LOAD
    put64(&mut ph, 32, 200);
    put32(&mut ph, 56, 0x6474_e551);
    elf.extend_from_slice(&ph);
    let payload_at = elf.len() as u64;
    elf.extend(std::iter::repeat_n(0xabu8, 64));
    let shoff = elf.len() as u64;
    put64(&mut elf, 40, shoff);
    let mut sh = vec![0u8; 128];
    put32(&mut sh, 64 + 4, 1);
    put64(&mut sh, 64 + 24, payload_at);
    put64(&mut sh, 64 + 32, 64);
    elf.extend_from_slice(&sh);

    let mut macho = vec![0u8; 32 + 72];
    macho[..4].copy_from_slice(&0xfeed_facfu32.to_le_bytes());
    macho[16..20].copy_from_slice(&1u32.to_le_bytes());
    macho[20..24].copy_from_slice(&72u32.to_le_bytes());
    macho[32..36].copy_from_slice(&0x19u32.to_le_bytes());
    macho[36..40].copy_from_slice(&72u32.to_le_bytes());
    macho[32 + 48..32 + 56].copy_from_slice(&104u64.to_le_bytes());
    let mut fat = vec![0u8; 8 + 20];
    fat[..4].copy_from_slice(&0xcafe_babeu32.to_be_bytes());
    fat[4..8].copy_from_slice(&1u32.to_be_bytes());
    fat[16..20].copy_from_slice(&28u32.to_be_bytes());

    let mut pe = vec![0u8; 64 + 24 + 40];
    pe[..2].copy_from_slice(b"MZ");
    pe[0x3c..0x40].copy_from_slice(&64u32.to_le_bytes());
    pe[64..68].copy_from_slice(b"PE\0\0");
    pe[64 + 6..64 + 8].copy_from_slice(&1u16.to_le_bytes());
    pe[88 + 16..88 + 20].copy_from_slice(&40u32.to_le_bytes());
    pe[88 + 20..88 + 24].copy_from_slice(&64u32.to_le_bytes());
    vec![elf, macho, fat, pe]
}

fn plugin_file(s: &Scratch, input: &[u8]) {
    let n = input.len() as u64;
    let _ = check_elf(&mut Cursor::new(input), n);
    let _ = check_macho(&mut Cursor::new(input), n);
    let _ = check_pe(&mut Cursor::new(input), n);
    // A size that disagrees with the bytes (the file shrank after `metadata`).
    let _ = check_elf(&mut Cursor::new(input), n.saturating_mul(2).max(1));
    if crate::fnv(input) % 8 == 0 {
        let _ = check_library_file(&s.write("libfuzz.so", input));
    }
}
