//! Dataset loaders: each turns one file into a [`RawScene`](crate::track::RawScene) of
//! timestamped world positions in metres.
//!
//! | loader | files | units | time |
//! |---|---|---|---|
//! | [`eth::load_obsmat`] | ETH/EWAP `obsmat.txt` | metres (columns 3 and 5) | 2.5 fps annotation; the frame step (6 or 10) gives the video rate |
//! | [`eth::load_homography`] | ETH `H.txt` | (row, col) pixels → metres | — |
//! | [`ucy::load_vsp`] | UCY `annotation.vsp` | pixels, origin at the image centre, → metres by `H` | 25 fps frames, irregular control points |
//! | [`sgan::load`] | sgan/Trajectron `frame id x y` | metres | 25 fps frames; `biwi_eth*` files use ETH's 15 fps frame numbers |
//! | [`sdd::load_raw`] | SDD `annotations.txt` | pixel boxes × `estimated_scales.yaml` | 30 fps |
//! | [`sdd::load_trajnet`] | SDD TrajNet split `frame id x y` | metres, 20-row chunks joined into walks | 30 fps frames, step 12 |
//!
//! SDD positions are in image axes (x right, y down); the loaders flip `y` so that every world
//! frame of the SDK is right-handed with `z` up.

pub mod eth;
pub mod sdd;
pub mod sgan;
pub mod ucy;

/// The most frequent positive difference between consecutive sorted values of each group
/// (ties go to the smaller step); `None` when no group has two values.
pub(crate) fn modal_step<'a>(groups: impl Iterator<Item = &'a [i64]>) -> Option<i64> {
    use std::collections::BTreeMap;
    let mut hist: BTreeMap<i64, usize> = BTreeMap::new();
    for g in groups {
        for w in g.windows(2) {
            let d = w[1] - w[0];
            if d > 0 {
                *hist.entry(d).or_default() += 1;
            }
        }
    }
    hist.into_iter()
        .max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0)))
        .map(|(d, _)| d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modal_step_picks_the_most_common_increment() {
        let a = [0i64, 6, 12, 18, 30];
        let b = [100i64, 106];
        assert_eq!(modal_step([&a[..], &b[..]].into_iter()), Some(6));
        let empty: [&[i64]; 1] = [&[1]];
        assert_eq!(modal_step(empty.into_iter()), None);
    }
}
