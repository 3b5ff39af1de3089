//! The ORCA planner plugin: the algorithm of `human2nav-orca-core` (re-exported here, see its
//! docs) behind the plugin entry point. The crate builds both as a `cdylib` (what the host
//! loads) and as a Rust library (its tests and benches).

pub use human2nav_orca_core::{
    NeighborSearch, OrcaConfig, OrcaError, OrcaPlanner, OrcaSim, kdtree, lp, orca, planner, sim,
};

human2nav_plugin::export_plugin! {
    name: "orca",
    version: env!("CARGO_PKG_VERSION"),
    factories: [
        planner(
            "orca",
            "ORCA reciprocal collision avoidance (RVO2 semantics), constant-velocity plan"
        ) => OrcaPlanner::from_init,
    ],
}
