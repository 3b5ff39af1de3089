//! `export_plugin!`: the one line of glue a plugin author writes.

/// Exports a plugin library: its name, version and factories.
///
/// Each factory names its kind (`constraint`, `embodiment` or `planner`), the name robot
/// profiles use, a one-line description, and a constructor
/// `fn(&PluginInit<'_>) -> Result<T, E>` where `T` implements the matching core trait
/// ([`ConstraintTerm`](human2nav_core::constraint::ConstraintTerm),
/// [`Embodiment`](human2nav_core::embodiment::Embodiment) or
/// [`Planner`](human2nav_core::Planner)) and `E: Into<InitError>`.
///
/// ```
/// use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
/// use human2nav_plugin::{InitError, PluginInit};
///
/// /// A flat cost per trajectory, set by the `cost` key of the plugin's TOML configuration.
/// struct Flat(f64);
///
/// impl Flat {
///     fn from_init(init: &PluginInit<'_>) -> Result<Self, InitError> {
///         #[derive(serde::Deserialize)]
///         #[serde(deny_unknown_fields)]
///         struct Config {
///             cost: f64,
///         }
///         let config: Config = init.config()?;
///         if !config.cost.is_finite() {
///             return Err(InitError::invalid("cost", "must be finite"));
///         }
///         Ok(Flat(config.cost))
///     }
/// }
///
/// impl ConstraintTerm for Flat {
///     fn name(&self) -> &str {
///         "flat"
///     }
///
///     fn evaluate(
///         &self,
///         _batch: TrajBatch<'_>,
///         _ctx: &ConstraintContext<'_>,
///         cost: &mut [f64],
///         grad: &mut [f64],
///     ) -> Result<(), ConstraintError> {
///         cost.fill(self.0);
///         grad.fill(0.0);
///         Ok(())
///     }
/// }
///
/// human2nav_plugin::export_plugin! {
///     name: "flat_cost",
///     version: "0.1.0",
///     factories: [
///         constraint("flat", "the same cost for every trajectory") => Flat::from_init,
///     ],
/// }
/// # fn main() {}
/// ```
///
/// The crate must be built as a `cdylib` (`crate-type = ["cdylib", "rlib"]` keeps it usable as
/// an ordinary dependency too) with unwinding panics (the default; `panic = "abort"` would
/// turn a plugin panic into a process abort). The expansion defines the entry symbol
/// `human2nav_plugin_entry`, so use the macro once per library.
#[macro_export]
macro_rules! export_plugin {
    (
        name: $name:expr,
        version: $version:expr,
        factories: [ $( $kind:ident ( $fname:expr, $fdesc:expr ) => $ctor:expr ),* $(,)? ] $(,)?
    ) => {
        const _: () = {
            static FACTORIES: &[$crate::abi::H2nFactory] = &[
                $( $crate::export_plugin!(@factory $kind, $fname, $fdesc, $ctor) ),*
            ];

            unsafe extern "C" fn find_factory(
                kind: u32,
                name: $crate::abi::H2nStr,
            ) -> *const $crate::abi::H2nFactory {
                // SAFETY: the host passes a readable name, per the ABI contract.
                unsafe { $crate::export::find_factory(FACTORIES, kind, name) }
            }

            static ENTRY: $crate::abi::H2nPluginEntry = $crate::abi::H2nPluginEntry {
                abi_version: $crate::abi::ABI_VERSION,
                struct_size: ::std::mem::size_of::<$crate::abi::H2nPluginEntry>() as u32,
                name: $crate::abi::H2nStr::new($name),
                version: $crate::abi::H2nStr::new($version),
                factories: FACTORIES.as_ptr(),
                factory_count: FACTORIES.len(),
                find_factory: ::std::option::Option::Some(find_factory),
            };

            /// The plugin's entry table (see `human2nav_plugin::abi`).
            #[unsafe(no_mangle)]
            pub extern "C" fn human2nav_plugin_entry() -> *const $crate::abi::H2nPluginEntry {
                &ENTRY
            }
        };
    };

    (@factory constraint, $fname:expr, $fdesc:expr, $ctor:expr) => {
        $crate::export_plugin!(@make H2N_KIND_CONSTRAINT, create_constraint, $fname, $fdesc, $ctor)
    };
    (@factory embodiment, $fname:expr, $fdesc:expr, $ctor:expr) => {
        $crate::export_plugin!(@make H2N_KIND_EMBODIMENT, create_embodiment, $fname, $fdesc, $ctor)
    };
    (@factory planner, $fname:expr, $fdesc:expr, $ctor:expr) => {
        $crate::export_plugin!(@make H2N_KIND_PLANNER, create_planner, $fname, $fdesc, $ctor)
    };
    (@factory $other:ident, $fname:expr, $fdesc:expr, $ctor:expr) => {
        ::std::compile_error!(concat!(
            "unknown plugin kind `", stringify!($other),
            "` (expected constraint, embodiment or planner)"
        ))
    };

    (@make $kind:ident, $create:ident, $fname:expr, $fdesc:expr, $ctor:expr) => {{
        unsafe extern "C" fn create(
            args: *const $crate::abi::H2nCreateArgs,
            out: *mut $crate::abi::H2nObject,
            error: *mut $crate::abi::H2nBuffer,
        ) -> $crate::abi::H2nStatus {
            // SAFETY: the host passes pointers honouring the ABI contract; the shim checks them.
            unsafe { $crate::export::$create(args, out, error, $ctor) }
        }
        $crate::abi::H2nFactory {
            struct_size: ::std::mem::size_of::<$crate::abi::H2nFactory>() as u32,
            kind: $crate::abi::$kind,
            name: $crate::abi::H2nStr::new($fname),
            description: $crate::abi::H2nStr::new($fdesc),
            create: ::std::option::Option::Some(create),
        }
    }};
}
