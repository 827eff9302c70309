//! Moving material points between the processes of a distributed run: a point's whole state
//! as numbers, and who sends which points where (the first pieces of the decomposition of
//! issue 14, `docs/distributed.md`; pure, no ECS, no MPI).
//!
//! **Ownership.** At the start of a load step a point belongs to the process of the slab of
//! cells its position lies in (`partition::slab_owners` over the slices along
//! `partition::slab_axis`). A process that holds a point another process owns sends it there,
//! whole, before the step's connectivity: [`plan_departures`] sorts a process's points into the
//! ones it keeps and one list per destination, each in the order the process held them (so a
//! process's points stay in `PointId` order when every process keeps them so).
//!
//! **A point's state as numbers** ([`PointRecord`]). Everything a later step depends on, as
//! `f64`s (exact: no text round trip; `u32` ids are exact in `f64`):
//!
//! ```text
//!   [ id, body, x (D), X (D), u (D), F (D×D, row by row), m, V0, V, n, history (n) ]
//! ```
//!
//! `x` the position, `X` the reference position, `u` the displacement, `F` the deformation
//! gradient, `m` the mass, `V0` and `V` the reference and current volumes; `history` is what the
//! modules keep per point (a material's committed plastic strain and hardening, a GIMP/CPDI
//! domain), `n` numbers long, opaque here. The stress and tangent are not sent: the stress
//! update recomputes them from `F` and the history at the first iteration of the step.
//! [`pack_points`] writes records one after another into one buffer (one message per
//! destination); [`unpack_points`] reads them back and refuses a buffer that does not hold
//! whole records.

use nalgebra::{SMatrix, SVector};

/// A material point's whole state between load steps (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct PointRecord<const D: usize> {
    /// `PointId`: the point's number in the serial order.
    pub id: u32,
    /// `BodyIndex`.
    pub body: u32,
    pub position: SVector<f64, D>,
    pub reference_position: SVector<f64, D>,
    pub displacement: SVector<f64, D>,
    pub deformation_gradient: SMatrix<f64, D, D>,
    pub mass: f64,
    pub reference_volume: f64,
    pub volume: f64,
    /// What the modules keep for the point, in their order (opaque here).
    pub history: Vec<f64>,
}

impl<const D: usize> PointRecord<D> {
    /// The numbers of a record before its history: id, body, x, X, u, F, m, V0, V, n.
    pub const FIXED: usize = 2 + 3 * D + D * D + 4;

    /// Appends this record to `buffer`.
    pub fn pack(&self, buffer: &mut Vec<f64>) {
        buffer.reserve(Self::FIXED + self.history.len());
        buffer.push(f64::from(self.id));
        buffer.push(f64::from(self.body));
        buffer.extend(self.position.iter());
        buffer.extend(self.reference_position.iter());
        buffer.extend(self.displacement.iter());
        buffer.extend(self.deformation_gradient.transpose().iter());
        buffer.extend([self.mass, self.reference_volume, self.volume]);
        buffer.push(self.history.len() as f64);
        buffer.extend(&self.history);
    }

    /// Reads the record at the start of `buffer`; returns it and the numbers it took.
    pub fn unpack(buffer: &[f64]) -> Result<(Self, usize), String> {
        let fixed = Self::FIXED;
        if buffer.len() < fixed {
            return Err(format!(
                "a point's record needs at least {fixed} numbers in {D}D, {} are left",
                buffer.len()
            ));
        }
        let count = |value: f64, what: &str| -> Result<u32, String> {
            if value >= 0.0 && value <= f64::from(u32::MAX) && value.fract() == 0.0 {
                Ok(value as u32)
            } else {
                Err(format!("a point's record has {value} as its {what}"))
            }
        };
        let vector = |at: usize| SVector::<f64, D>::from_column_slice(&buffer[at..at + D]);
        let history = count(buffer[fixed - 1], "history length")? as usize;
        let end = fixed + history;
        if buffer.len() < end {
            return Err(format!(
                "a point's record announces {history} history numbers, {} are left",
                buffer.len() - fixed
            ));
        }
        let f = 2 + 3 * D;
        let record = Self {
            id: count(buffer[0], "id")?,
            body: count(buffer[1], "body")?,
            position: vector(2),
            reference_position: vector(2 + D),
            displacement: vector(2 + 2 * D),
            deformation_gradient: SMatrix::<f64, D, D>::from_row_slice(&buffer[f..f + D * D]),
            mass: buffer[f + D * D],
            reference_volume: buffer[f + D * D + 1],
            volume: buffer[f + D * D + 2],
            history: buffer[fixed..end].to_vec(),
        };
        Ok((record, end))
    }
}

/// The records one after another in one buffer (one message).
pub fn pack_points<const D: usize>(records: &[PointRecord<D>]) -> Vec<f64> {
    let mut buffer = Vec::new();
    for record in records {
        record.pack(&mut buffer);
    }
    buffer
}

/// The records of a buffer written by [`pack_points`]; an error if it does not hold whole
/// records.
pub fn unpack_points<const D: usize>(mut buffer: &[f64]) -> Result<Vec<PointRecord<D>>, String> {
    let mut records = Vec::new();
    while !buffer.is_empty() {
        let (record, used) = PointRecord::<D>::unpack(buffer)
            .map_err(|why| format!("point {} of the message: {why}", records.len() + 1))?;
        records.push(record);
        buffer = &buffer[used..];
    }
    Ok(records)
}

/// Which of a process's points stay and which go where, at the start of a load step.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Departures {
    /// Indices (into the process's points) of the points it keeps, in order.
    pub kept: Vec<usize>,
    /// For every other process, in increasing rank: the indices of the points it gets, in
    /// order (empty lists left out).
    pub sent: Vec<(usize, Vec<usize>)>,
}

/// Sorts the points a process `rank` holds by their owners this step (`owners[i]`: the
/// process of point `i`, from the slab of its position): the ones it keeps, and one list per
/// destination, each in the order the points are held.
pub fn plan_departures(owners: &[usize], rank: usize) -> Departures {
    let mut departures = Departures::default();
    let mut by_destination: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (index, &owner) in owners.iter().enumerate() {
        if owner == rank {
            departures.kept.push(index);
        } else {
            by_destination.entry(owner).or_default().push(index);
        }
    }
    departures.sent = by_destination.into_iter().collect();
    departures
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record<const D: usize>(id: u32, history: usize) -> PointRecord<D> {
        let value = |k: usize| (id as f64 + 1.0) * 0.1 + k as f64 * std::f64::consts::PI;
        PointRecord {
            id,
            body: id % 3,
            position: SVector::from_fn(|a, _| value(a)),
            reference_position: SVector::from_fn(|a, _| value(10 + a)),
            displacement: SVector::from_fn(|a, _| -value(20 + a)),
            deformation_gradient: SMatrix::from_fn(|i, j| value(30 + D * i + j)),
            mass: value(40),
            reference_volume: value(41),
            volume: value(42) * 1e-300,
            history: (0..history).map(|k| value(50 + k).sin()).collect(),
        }
    }

    fn round_trip<const D: usize>() {
        let records: Vec<PointRecord<D>> =
            (0..5).map(|id| record(id, (id as usize) % 3 * 7)).collect();
        let buffer = pack_points(&records);
        let expected: usize = records
            .iter()
            .map(|r| PointRecord::<D>::FIXED + r.history.len())
            .sum();
        assert_eq!(buffer.len(), expected);
        // exact: the same values (the ids, and f64s compared by value)
        let back = unpack_points::<D>(&buffer).unwrap();
        assert_eq!(back, records);
        // the layout the module docs give: id, body, x, X, u, F row by row, m, V0, V, n
        let first = &records[0];
        let f = 2 + 3 * D;
        assert_eq!(buffer[0], f64::from(first.id));
        assert_eq!(buffer[2 + D], first.reference_position[0]);
        assert_eq!(buffer[f + D - 1], first.deformation_gradient[(0, D - 1)]);
        assert_eq!(buffer[f + D * D], first.mass);
        assert_eq!(buffer[f + D * D + 2].to_bits(), first.volume.to_bits());
    }

    #[test]
    fn a_point_record_round_trips_exactly_in_1d_2d_and_3d() {
        round_trip::<1>();
        round_trip::<2>();
        round_trip::<3>();
        assert_eq!(PointRecord::<2>::FIXED, 2 + 6 + 4 + 4);
    }

    #[test]
    fn a_buffer_without_whole_records_is_refused() {
        let records = vec![record::<2>(7, 3), record::<2>(8, 0)];
        let buffer = pack_points(&records);
        for cut in [1, PointRecord::<2>::FIXED - 1, PointRecord::<2>::FIXED + 2] {
            let error = unpack_points::<2>(&buffer[..cut]).unwrap_err();
            assert!(error.contains("point 1 of the message"), "{error}");
        }
        let error = unpack_points::<2>(&buffer[..buffer.len() - 1]).unwrap_err();
        assert!(error.contains("point 2"), "{error}");
        let mut bad = buffer.clone();
        bad[0] = -1.0;
        assert!(unpack_points::<2>(&bad).unwrap_err().contains("id"));
        let mut bad = buffer;
        bad[PointRecord::<2>::FIXED - 1] = 2.5;
        assert!(
            unpack_points::<2>(&bad)
                .unwrap_err()
                .contains("history length")
        );
        assert_eq!(unpack_points::<2>(&[]).unwrap(), vec![]);
    }

    /// Every point is kept or sent exactly once, to its owner, in the order held.
    #[test]
    fn departures_send_each_point_to_its_owner_once_in_order() {
        let owners = [1, 0, 2, 1, 1, 2, 0, 3];
        let plan = plan_departures(&owners, 1);
        assert_eq!(plan.kept, vec![0, 3, 4]);
        assert_eq!(
            plan.sent,
            vec![(0, vec![1, 6]), (2, vec![2, 5]), (3, vec![7])]
        );
        for rank in 0..4 {
            let plan = plan_departures(&owners, rank);
            let mut seen: Vec<usize> = plan.kept.clone();
            for (to, list) in &plan.sent {
                assert_ne!(*to, rank);
                assert!(list.iter().all(|&i| owners[i] == *to));
                assert!(list.windows(2).all(|w| w[0] < w[1]));
                seen.extend(list);
            }
            seen.sort_unstable();
            assert_eq!(seen, (0..owners.len()).collect::<Vec<_>>());
        }
        // nothing held, or everything kept
        assert_eq!(plan_departures(&[], 0), Departures::default());
        assert!(plan_departures(&[2, 2], 2).sent.is_empty());
    }
}
