//! Tests of `rounds`.

use super::*;

#[test]
fn only_a_direct_mapped_cache_waits_for_room() {
    // Nothing in flight: start. Batches in flight not yet down to their tails: wait.
    assert!(next_batch_may_start(false, false, false, false, (100, 100)));
    assert!(!next_batch_may_start(true, false, false, true, (0, 100)));
    // Tails whose last round used most of the lines: lru starts the next batch, a
    // direct-mapped cache waits until at most half the lines were used.
    assert!(next_batch_may_start(true, true, false, true, (90, 100)));
    assert!(!next_batch_may_start(true, true, false, false, (90, 100)));
    assert!(next_batch_may_start(true, true, false, false, (50, 100)));
}

#[test]
fn a_batch_starts_beside_a_few_waiting_faults_only_when_the_nodes_are_resident() {
    // None waiting: always. Half the lines' worth: with the nodes resident only.
    assert!(few_left_waiting(0, 100, false));
    assert!(few_left_waiting(0, 100, true));
    assert!(few_left_waiting(50, 100, true));
    assert!(!few_left_waiting(50, 100, false));
    assert!(!few_left_waiting(51, 100, true));
    assert!(!few_left_waiting(1, 100, false));
}

#[test]
fn a_round_that_moved_no_ray_and_listed_no_block_is_a_stall() {
    assert!(stalled(5, false, 0));
    // Rays moved, or asked for blocks (served next round), or none is left.
    assert!(!stalled(5, true, 0));
    assert!(!stalled(5, false, 1));
    assert!(!stalled(0, false, 0));
}

#[test]
fn a_batch_starts_where_those_in_flight_resume_in_full() {
    // Not down to their tails, but every fault of the last round got a line.
    assert!(next_batch_may_start(true, false, true, true, (100, 100)));
    assert!(!next_batch_may_start(true, false, false, true, (100, 100)));
}

#[test]
fn a_fault_list_reads_its_requesters_and_serves_the_oldest_batch_first() {
    // Capacity 4, three faults listed, then the listed blocks' least requesters, complemented
    // (shaders/requesters.wgsl): block 1's a kernel without rays (1).
    let who = |lane: u32, ray: u32| (lane << REQUESTER_LANE_SHIFT) | ray;
    let header = FaultHeader {
        count: 3,
        ..Default::default()
    };
    let mut bytes = bytemuck::bytes_of(&header).to_vec();
    let words = [2u32, 1, 0, 7, !who(2, 5), 1, 0, !who(0, 3)];
    bytes.extend(words.iter().flat_map(|w| w.to_ne_bytes()));
    let mut f = FaultList::read(&bytes, 4);
    assert_eq!(f.blocks, [2, 1, 0]);
    assert_eq!(requester_lane(f.requesters[0]), Some((2, 5)));
    assert_eq!(requester_lane(f.requesters[1]), None);
    // Block 0 listed but never requested (cannot happen) reads as no requester.
    assert_eq!(requester_lane(f.requesters[2]), None);
    // Ages 3, none (last), none: the oldest first, ties by block.
    f.order_by(&[3, u64::MAX, u64::MAX]);
    assert_eq!(f.blocks, [2, 0, 1]);
    assert_eq!(f.requesters[0], who(2, 5));
}

#[test]
fn faults_are_served_by_batch_age_then_ray_slot() {
    // An older batch's last ray before a newer batch's first; within a batch, by slot.
    assert!(serve_order(3, (1 << 28) - 1) < serve_order(4, 0));
    assert!(serve_order(4, 7) < serve_order(4, 8));
    // Listed as the GPU's threads interleaved them; one without a requester (u64::MAX)
    // last.
    let keys = [
        u64::MAX,
        serve_order(1, 900),
        serve_order(0, 5),
        serve_order(1, 2),
    ];
    let mut f = FaultList {
        header: FaultHeader::default(),
        blocks: vec![9, 10, 11, 12],
        requesters: vec![0; 4],
    };
    f.order_by(&keys);
    assert_eq!(f.blocks, [11, 12, 10, 9]);
}

#[test]
fn a_batch_counts_each_block_once_to_the_tile_that_listed_it_first() {
    let rows = Tiling::new(64, 32, 32);
    let mut run = LaneRun::new(Rect::whole(64, 32), rows, 0, 4, 3);
    run.note_fault(9, 1);
    run.note_fault(9, 2);
    run.note_fault(8, 2);
    // A block listed again (it got no line) and a slot past the batch's tiles count nothing.
    run.note_fault(8, 0);
    run.note_fault(7, 3);
    assert_eq!(run.tile_faults, [0, 1, 1]);
    // Into the density at the batch's tiles (4..7); the others keep what they had.
    let mut d = FaultDensity::new(Rect::whole(64, 32), rows);
    d.note(rows, 0..8, &[5; 8]);
    d.note(rows, 4..7, &run.tile_faults);
    let got: Vec<f64> = (0..8).map(|t| d.per_tile[d.slot(rows, t)]).collect();
    assert_eq!(got, [5.0, 5.0, 5.0, 5.0, 0.0, 1.0, 1.0, 5.0]);
}

#[test]
fn a_batch_takes_tiles_until_their_faults_reach_the_target() {
    // 8x4 tiles in rows; every tile of the batch that traced them faulted 10 times.
    let rows = Tiling::new(64, 32, 32);
    let mut d = FaultDensity::new(Rect::whole(64, 32), rows);
    d.note(rows, 0..32, &[10; 32]);
    assert_eq!(d.batch(rows, 0, 1..=32, 45.0), 5);
    assert_eq!(d.batch(rows, 0, 1..=32, 50.0), 5);
    assert_eq!(d.batch(rows, 0, 1..=32, 51.0), 6);
    // At least `least` tiles, at most `most`.
    assert_eq!(d.batch(rows, 0, 8..=32, 5.0), 8);
    assert_eq!(d.batch(rows, 0, 1..=3, 1e9), 3);
}

#[test]
fn dense_tiles_make_smaller_batches() {
    // Every tile of the first two rows faulted 6 times, of the last two once.
    let rows = Tiling::new(64, 32, 16);
    let mut d = FaultDensity::new(Rect::whole(64, 32), rows);
    d.note(rows, 0..16, &[6; 16]);
    d.note(rows, 16..32, &[1; 16]);
    assert_eq!(d.batch(rows, 0, 1..=32, 25.0), 5);
    assert_eq!(d.batch(rows, 16, 1..=16, 25.0), 16);
    assert_eq!(d.batch(rows, 16, 1..=16, 8.0), 8);
}

#[test]
fn densities_belong_to_tile_positions_not_to_batch_order() {
    // Noted in one order (bands 2 tiles wide, every other one upward), read in another
    // (rows): the faults stay with the tiles that made them.
    let (w, h) = (64, 32);
    let bands = Tiling {
        tiles_x: 8,
        tiles_y: 4,
        band: 2,
    };
    let rows = Tiling::new(w, h, 32);
    let mut d = FaultDensity::new(Rect::whole(w, h), bands);
    // The first band: tiles x 0..2 of every row, 8 faults each.
    d.note(bands, 0..8, &[8; 8]);
    for t in 0..32 {
        let expect = if t % 8 < 2 { 8.0 } else { 0.0 };
        assert_eq!(d.per_tile[d.slot(rows, t)], expect, "tile {t}");
    }
}
