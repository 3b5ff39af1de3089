//! Entry tables a broken plugin could return, validated in-process exactly as after
//! `dlopen` (the tables are statics of this test binary instead of a library's).

use super::*;

/// A plugin that claims a longer message than it wrote shows what it wrote, not the NUL
/// bytes after it; control characters become spaces.
#[test]
fn a_claimed_error_length_is_not_trusted_past_the_text() {
    let mut buf = vec![0u8; 1009];
    buf[..4].copy_from_slice(b"oops");
    assert_eq!(buffer_text(&buf, 1009), "oops");
    let bell = b"bad\x07value\x1b[2J";
    assert_eq!(buffer_text(bell, bell.len()), "bad value [2J");
    assert_eq!(buffer_text(b"longer", 4096), "longer \u{2026}");
}

unsafe extern "C" fn create_nothing(
    _: *const H2nCreateArgs,
    _: *mut H2nObject,
    _: *mut H2nBuffer,
) -> H2nStatus {
    H2N_ERROR
}

fn factory(name: &'static str, create: Option<CreateFn>) -> H2nFactory {
    H2nFactory {
        struct_size: std::mem::size_of::<H2nFactory>() as u32,
        kind: H2N_KIND_CONSTRAINT,
        name: H2nStr::new(name),
        description: H2nStr::new("test"),
        create,
    }
}

fn entry(factories: &'static [H2nFactory]) -> H2nPluginEntry {
    H2nPluginEntry {
        abi_version: ABI_VERSION,
        struct_size: std::mem::size_of::<H2nPluginEntry>() as u32,
        name: H2nStr::new("broken"),
        version: H2nStr::new("0"),
        factories: factories.as_ptr(),
        factory_count: factories.len(),
        find_factory: None,
    }
}

fn load(e: H2nPluginEntry) -> (Result<PluginLibrary, PluginError>, Vec<Check>) {
    let e: &'static H2nPluginEntry = Box::leak(Box::new(e));
    let mut checks = Vec::new();
    // SAFETY: a leaked (static) table whose fields are as declared or deliberately wrong
    // in ways the validation must catch before reading out of bounds.
    let r = unsafe { PluginLibrary::from_entry(Path::new("/lib/libbroken.so"), e, &mut checks) };
    (r, checks)
}

fn leak(f: Vec<H2nFactory>) -> &'static [H2nFactory] {
    Box::leak(f.into_boxed_slice())
}

#[test]
fn a_valid_table_loads_and_lists_its_checks() {
    let (r, checks) = load(entry(leak(vec![
        factory("a", Some(create_nothing)),
        factory("b", Some(create_nothing)),
    ])));
    let lib = r.expect("valid");
    assert_eq!(lib.factories().len(), 2);
    assert!(checks.iter().all(Check::passed), "{checks:?}");
    assert!(
        checks
            .iter()
            .any(|c| c.item == "factory 1 (constraint `b`)")
    );
}

#[test]
fn a_null_create_slot_names_the_file_the_table_and_the_slot() {
    let (r, checks) = load(entry(leak(vec![
        factory("a", Some(create_nothing)),
        factory("b", None),
    ])));
    let err = r.expect_err("null create");
    assert_eq!(
        err.to_string(),
        "/lib/libbroken.so: the factory table entry 1 (constraint `b`) has a null `create` \
         (a required function)"
    );
    assert!(checks.last().is_some_and(|c| !c.passed()));
}

#[test]
fn an_absurd_factory_count_is_refused_without_allocating() {
    let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
    e.factory_count = 1 << 40;
    let err = load(e).0.expect_err("count");
    assert_eq!(
        err.to_string(),
        "/lib/libbroken.so: the factory count is 1099511627776, more than this host \
         accepts (256)"
    );
}

#[test]
fn wrong_table_sizes_are_refused() {
    let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
    e.struct_size = 8;
    let err = load(e).0.expect_err("entry size");
    assert!(
        err.to_string()
            .contains("the entry table declares 8 bytes (struct_size); this host needs"),
        "{err}"
    );
    let mut f = factory("a", Some(create_nothing));
    f.struct_size = 1 << 30;
    let err = load(entry(leak(vec![f]))).0.expect_err("factory size");
    assert!(
        err.to_string()
            .contains("factory table entry 0 declares 1073741824"),
        "{err}"
    );
    // Two factories of different sizes cannot be one array.
    let mut g = factory("b", Some(create_nothing));
    g.struct_size += 8;
    let err = load(entry(leak(vec![factory("a", Some(create_nothing)), g])))
        .0
        .expect_err("stride");
    assert!(err.to_string().contains("factory 1 is"), "{err}");
}

#[test]
fn bad_strings_and_duplicates_are_refused() {
    let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
    e.name = H2nStr {
        ptr: std::ptr::null(),
        len: 5,
    };
    assert!(
        load(e)
            .0
            .expect_err("null name")
            .to_string()
            .contains("is null with length 5")
    );
    let mut e = entry(leak(vec![factory("a", Some(create_nothing))]));
    e.version = H2nStr {
        ptr: "x".as_ptr(),
        len: 1 << 40,
    };
    let err = load(e).0.expect_err("long version");
    assert!(err.to_string().contains("the limit is 256"), "{err}");
    let err = load(entry(leak(vec![
        factory("a", Some(create_nothing)),
        factory("a", Some(create_nothing)),
    ])))
    .0
    .expect_err("duplicate");
    assert!(err.to_string().contains("repeats constraint `a`"), "{err}");
}

#[test]
fn worker_thread_names_keep_only_safe_characters() {
    assert_eq!(thread_name("personal_space"), "h2n-personal_sp");
    assert_eq!(thread_name("a\0b c/é"), "h2n-abc");
}

#[test]
fn agent_histories_are_linked_into_the_flat_buffer() {
    let agents = vec![
        AgentState {
            id: 1,
            position: [0.0, 0.0],
            velocity: [0.0, 0.0],
            radius: 0.3,
            history: vec![[1.0, 2.0], [3.0, 4.0]],
        },
        AgentState {
            id: 2,
            position: [0.0, 0.0],
            velocity: [0.0, 0.0],
            radius: 0.3,
            history: vec![],
        },
        AgentState {
            id: 3,
            position: [0.0, 0.0],
            velocity: [0.0, 0.0],
            radius: 0.3,
            history: vec![[5.0, 6.0]],
        },
    ];
    let (mut abi, mut flat) = (Vec::new(), Vec::new());
    load_agents(&agents, &mut abi, &mut flat);
    link_histories(&mut abi, &flat);
    assert_eq!(flat, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    assert!(abi[1].history.is_null());
    // SAFETY: the pointers point into `flat`, which is alive.
    unsafe {
        assert_eq!(*abi[0].history, 1.0);
        assert_eq!(*abi[2].history.add(1), 6.0);
    }
}
