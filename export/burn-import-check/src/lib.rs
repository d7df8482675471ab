//! The graphs of `models/spheres`, as burn-import generated them.

/// The coarse network.
pub mod coarse {
    include!(concat!(env!("OUT_DIR"), "/model/coarse.rs"));
}

/// The fine network.
pub mod fine {
    include!(concat!(env!("OUT_DIR"), "/model/fine.rs"));
}
