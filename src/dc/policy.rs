//! The host's cache policy between traversal rounds (docs/ARCHITECTURE.md, The round loop): the
//! round's fault list comes in; which blocks to load into which lines, what each load evicts, and
//! the changes to the GPU's block-row table go out. Pure bookkeeping, so it is tested without a
//! GPU; `gpu::faults` applies its plans.
//!
//! The first fault for a line wins it; the round's other faults on that line fault again next
//! round. Every round with faults so loads at least one block, and a single-line cache still
//! finishes.

use super::NONE;
use super::{CacheMap, cache_line};
use crate::blocks::ranks::Ranks;
use crate::error::{Error, Result};
use crate::traces::record::Fault;

/// A rank's cache: what each line holds and the row of every block on its GPU.
#[derive(Clone, Debug)]
pub struct CachePolicy {
    ranks: Ranks,
    map: CacheMap,
    lines: u32,
    /// The first cache row: the resident rows come before it.
    cache_row: u32,
    /// Block in each line, `NONE` when empty.
    tags: Vec<u32>,
    /// Row of every block (`NONE` when absent): the GPU's `block_rows` table.
    block_rows: Vec<u32>,
    /// Rounds planned so far, and the round each line was last loaded or used in (0: never):
    /// `Lru`'s recency.
    round: u64,
    stamps: Vec<u64>,
    /// The lines `Lru` keeps in the next plan (`mark_used`): those holding a node block the
    /// last round used, and those holding the triangle block a ray still live after it used
    /// last. Blocks `0..node_blocks` are node blocks.
    kept: Vec<bool>,
    node_blocks: u32,
    /// Per node block, the blocks it leads to (`Format::child_blocks`), learnt when its bytes
    /// pass through the host (`learn_children`); empty while unknown, and no list at all
    /// without `fetch_ahead`. `Lru` loads them into lines no round needs, beside the faulted
    /// block, so that its rays go on into them.
    children: Vec<Box<[u32]>>,
    fetch_ahead: bool,
}

impl RoundPlan {
    /// The faults that got a line this round (the loads before those fetched ahead).
    pub fn served(&self) -> usize {
        self.loads.len() - self.ahead as usize
    }
}

/// A block to fetch into a cache line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Load {
    pub block: u32,
    pub line: u32,
    /// The line's row in the block store.
    pub row: u32,
}

/// What to do after one round's faults.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RoundPlan {
    /// One record per fault, in the order of the GPU's list (for the trace).
    pub faults: Vec<Fault>,
    /// The blocks to fetch and where they go: the faults served, then the blocks fetched ahead.
    pub loads: Vec<Load>,
    /// Of `loads`, the last this many are fetched ahead (children of faulted blocks).
    pub ahead: u32,
    /// Entries of the block-row table to rewrite, in order: `(block, row)`, `row` `NONE` for an
    /// evicted block.
    pub rows: Vec<(u32, u32)>,
}

impl CachePolicy {
    /// An empty cache of `lines` lines for rank `ranks.rank` of a model of `count` blocks: owned
    /// and replicated blocks at their resident rows, every other block absent.
    pub fn new(
        ranks: Ranks,
        map: CacheMap,
        lines: u32,
        count: u32,
        node_blocks: u32,
    ) -> CachePolicy {
        let block_rows = (0..count)
            .map(|k| ranks.resident_row(k, count).unwrap_or(NONE))
            .collect();
        CachePolicy {
            ranks,
            map,
            lines,
            cache_row: ranks.resident_rows(count),
            tags: vec![NONE; lines as usize],
            block_rows,
            round: 0,
            stamps: vec![0; lines as usize],
            kept: vec![false; lines as usize],
            node_blocks,
            children: Vec::new(),
            fetch_ahead: false,
        }
    }

    /// With `on` (and `Lru`), each round also fetches the children of the node blocks its
    /// faults load, into lines that neither the last round used nor a live ray keeps
    /// (`Settings::fetch_ahead`).
    pub fn with_fetch_ahead(mut self, on: bool) -> CachePolicy {
        self.fetch_ahead = on && self.map == CacheMap::Lru;
        if self.fetch_ahead {
            self.children = vec![Box::default(); self.node_blocks as usize];
        }
        self
    }

    /// Whether node block `k`'s children are still to learn.
    pub fn wants_children(&self, k: u32) -> bool {
        self.fetch_ahead && k < self.node_blocks && self.children[k as usize].is_empty()
    }

    /// Records the blocks node block `k` leads to (`Format::child_blocks` of its bytes). A child
    /// past the model's blocks is an error naming both: the block's bytes are not this model's.
    pub fn learn_children(&mut self, k: u32, children: Vec<u32>) -> Result<()> {
        let count = self.block_rows.len();
        if let Some(c) = children.iter().find(|&&c| c as usize >= count) {
            return Err(Error::Invalid(format!(
                "node block {k} (rank {}'s) leads to block {c}, past the model's {count} blocks",
                self.ranks.owner(k)
            )));
        }
        if self.fetch_ahead && k < self.node_blocks {
            self.children[k as usize] = children.into_boxed_slice();
        }
        Ok(())
    }

    pub fn ranks(&self) -> Ranks {
        self.ranks
    }

    pub fn map(&self) -> CacheMap {
        self.map
    }

    pub fn lines(&self) -> u32 {
        self.lines
    }

    /// The first cache row (= the number of resident rows).
    pub fn cache_row(&self) -> u32 {
        self.cache_row
    }

    /// The row table the GPU starts with.
    pub fn block_rows(&self) -> &[u32] {
        &self.block_rows
    }

    /// Whether every node block is on this rank's GPU (replicated), so that only triangle and
    /// attribute blocks fault.
    pub fn nodes_resident(&self) -> bool {
        self.ranks.replicated >= self.node_blocks
    }

    /// The fewest fault rounds in which any schedule of rays could bring a frame's borrowed
    /// blocks (`looked_up[k]` for block k) through this cache: a round loads at most one block
    /// into each line (`plan_round`, fetching ahead included), only rounds with faults load, and
    /// at most one of the blocks a line takes can be there when the frame begins. A
    /// direct-mapped cache (`Ize`, `Demarle`) needs as many rounds as the blocks of its fullest
    /// line, less one; `Lru`, which puts a block in any line, the blocks over the lines, less
    /// one. The order in which rays reach their blocks (a child's block only after its
    /// parent's) can only add rounds: the bound shows how far a scheduler is from what the
    /// cache's size and mapping allow (docs/ARCHITECTURE.md, The distributed cache).
    pub fn fault_round_bound(&self, looked_up: &[bool]) -> u32 {
        let blocks = (0u32..).zip(looked_up).filter(|(_, u)| **u).map(|(k, _)| k);
        let most = if self.map == CacheMap::Lru {
            (blocks.count() as u64).div_ceil(u64::from(self.lines))
        } else {
            let mut per_line = vec![0u64; self.lines as usize];
            for k in blocks {
                per_line[cache_line(self.map, self.ranks, self.lines, k) as usize] += 1;
            }
            per_line.into_iter().max().unwrap_or(0)
        };
        most.saturating_sub(1).min(u64::from(u32::MAX)) as u32
    }

    /// The block line `line` holds, if any.
    pub fn tag(&self, line: u32) -> Option<u32> {
        let t = self.tags[line as usize];
        (t != NONE).then_some(t)
    }

    /// Records the lines the GPU found a block in during the round about to be planned
    /// (`used[line]` nonzero), and those whose triangle block a ray still live after it used
    /// last (`kept[line]` nonzero; shared/dc.wgsl, `keep_line`).
    pub fn mark_used(&mut self, used: &[u32], kept: &[u32]) {
        self.kept.iter_mut().for_each(|k| *k = false);
        for (line, &u) in used.iter().enumerate().take(self.lines as usize) {
            if u != 0 {
                self.stamps[line] = self.round + 1;
                // A node block's rays are many and its children all over the tree: kept
                // whenever used.
                self.kept[line] = self.tags[line] < self.node_blocks;
            }
        }
        for (k, &u) in self.kept.iter_mut().zip(kept) {
            *k |= u != 0;
        }
    }

    /// Plans a round: `faults` is the GPU's deduplicated fault list, `waiting[line]` the rays
    /// that waited on each line. The plan's loads are taken as done: fetch and upload them
    /// before the next dispatch, or give up the frame.
    pub fn plan_round(&mut self, faults: &[u32], waiting: &[u32]) -> RoundPlan {
        self.round += 1;
        let mut claimed = vec![false; self.lines as usize];
        let mut plan = RoundPlan::default();
        // Lru: the round's lines, least recently loaded or used first (empty lines before all),
        // at most one fault each; faults past them fault again. Kept lines (`mark_used`) stay:
        // their rays resume next to them (evicting them refetched a third of a 1/32 cache's
        // blocks, docs/ARCHITECTURE.md, The distributed cache). Only when every line is kept
        // does the least recent one go, so that every round with faults loads a block.
        let mut free = Vec::new();
        let mut spare: Vec<u32> = Vec::new();
        if self.map == CacheMap::Lru {
            let mut order: Vec<u32> = (0..self.lines).collect();
            order.sort_by_key(|&l| (self.stamps[l as usize], l));
            free = order
                .iter()
                .copied()
                .filter(|&l| !self.kept[l as usize])
                .collect();
            if free.is_empty() {
                free.extend(order.first());
            }
            // Lines neither kept nor used by the last round, past those the faults take: room
            // to fetch ahead.
            spare = free
                .iter()
                .skip(faults.len())
                .copied()
                .filter(|&l| self.stamps[l as usize] < self.round)
                .collect();
            spare.reverse();
            free.truncate(faults.len());
            free.reverse();
        }
        for &k in faults {
            let (line, first) = match self.map {
                CacheMap::Lru => match free.pop() {
                    Some(l) => (l, true),
                    // No line left this round: the bucket only names where it waits.
                    None => (cache_line(self.map, self.ranks, self.lines, k), false),
                },
                _ => {
                    let l = cache_line(self.map, self.ranks, self.lines, k);
                    (l, !std::mem::replace(&mut claimed[l as usize], true))
                }
            };
            let old = self.tags[line as usize];
            plan.faults.push(Fault {
                block: k,
                owner: self.ranks.owner(k),
                line,
                evicted: (first && old != NONE).then_some(old),
                waiting: waiting
                    .get(cache_line(self.map, self.ranks, self.lines, k) as usize)
                    .copied()
                    .unwrap_or(0),
                served: first,
            });
            if first {
                plan.loads.push(Load {
                    block: k,
                    line,
                    row: self.cache_row + line,
                });
            }
        }
        if self.fetch_ahead && !spare.is_empty() {
            self.fetch_ahead(&mut plan, &mut spare);
        }
        for l in &plan.loads {
            self.stamps[l.line as usize] = self.round;
            let old = std::mem::replace(&mut self.tags[l.line as usize], l.block);
            for (b, r) in [(old, NONE), (l.block, l.row)] {
                if b != NONE {
                    self.block_rows[b as usize] = r;
                    plan.rows.push((b, r));
                }
            }
        }
        plan
    }
}

impl CachePolicy {
    /// Adds loads of the served node blocks' children that are absent, into `spare` lines (taken
    /// from the back), a child of each served block in turn, until the lines or the children run
    /// out. One level: fetching the children's children too, or into every line not kept,
    /// fetched more blocks for more fault rounds (docs/ARCHITECTURE.md, The distributed cache).
    fn fetch_ahead(&self, plan: &mut RoundPlan, spare: &mut Vec<u32>) {
        let lists: Vec<&[u32]> = plan
            .loads
            .iter()
            .filter(|l| l.block < self.node_blocks)
            .map(|l| &*self.children[l.block as usize])
            .collect();
        let mut planned: std::collections::HashSet<u32> =
            plan.loads.iter().map(|l| l.block).collect();
        let mut ahead = Vec::new();
        let most = lists.iter().map(|c| c.len()).max().unwrap_or(0);
        'fill: for i in 0..most {
            for c in &lists {
                let Some(&k) = c.get(i) else { continue };
                if self.block_rows[k as usize] != NONE || !planned.insert(k) {
                    continue;
                }
                let Some(line) = spare.pop() else {
                    break 'fill;
                };
                ahead.push(Load {
                    block: k,
                    line,
                    row: self.cache_row + line,
                });
            }
        }
        plan.ahead = ahead.len() as u32;
        plan.loads.extend(ahead);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(n: u32, rank: u32, map: CacheMap, lines: u32, count: u32) -> CachePolicy {
        CachePolicy::new(Ranks::new(n, rank).unwrap(), map, lines, count, 0)
    }

    #[test]
    fn the_nodes_are_resident_when_every_node_block_is_replicated() {
        // 3 node blocks of 10: the root alone leaves two to fault on, all three none.
        let ranks = Ranks::new(4, 1).unwrap();
        let root = CachePolicy::new(ranks, CacheMap::Lru, 2, 10, 3);
        assert!(!root.nodes_resident());
        let nodes = CachePolicy::new(ranks.replicating(3), CacheMap::Lru, 2, 10, 3);
        assert!(nodes.nodes_resident());
    }

    #[test]
    fn starts_with_resident_rows_only() {
        // Rank 1 of 2, 6 blocks: owns 1, 3, 5 at rows 0..3, the root at row 3, cache from row 4.
        let p = policy(2, 1, CacheMap::Ize, 2, 6);
        assert_eq!(p.cache_row(), 4);
        assert_eq!(p.block_rows(), &[3, 0, NONE, 1, NONE, 2]);
        assert_eq!((p.tag(0), p.tag(1)), (None, None));
    }

    #[test]
    fn first_fault_on_a_line_wins() {
        // One line: of three faults only the first is loaded; the others fault again.
        let mut p = policy(2, 0, CacheMap::Ize, 1, 10);
        let plan = p.plan_round(&[3, 5, 7], &[3]);
        assert_eq!(
            plan.loads,
            vec![Load {
                block: 3,
                line: 0,
                row: 5
            }]
        );
        let served: Vec<bool> = plan.faults.iter().map(|f| f.served).collect();
        assert_eq!(served, vec![true, false, false]);
        assert!(plan.faults.iter().all(|f| f.waiting == 3 && f.owner == 1));
        assert_eq!(plan.rows, vec![(3, 5)]);
        assert_eq!(p.tag(0), Some(3));
    }

    #[test]
    fn the_fault_round_bound_counts_the_fullest_line_or_every_line() {
        // Rank 0 of 2, 3 lines: blocks 1, 3, 5, 7, 9, 11, 13 are borrowed. Demarle puts k in
        // line k mod 3: 3, 9 in line 0; 1, 7, 13 in line 1; 5, 11 in line 2. Ize numbers the
        // borrowed blocks 0.. (block 2i + 1 is the i-th) before the mod: 1, 7, 13 (i = 0, 3, 6)
        // in line 0; 3, 9 in 1; 5, 11 in 2.
        let mut looked_up = vec![false; 16];
        for k in [1, 3, 5, 7, 9, 11, 13] {
            looked_up[k] = true;
        }
        for map in [CacheMap::Demarle, CacheMap::Ize] {
            // Three blocks in one line: two loads at least, one a round.
            assert_eq!(
                policy(2, 0, map, 3, 16).fault_round_bound(&looked_up),
                2,
                "{map:?}"
            );
        }
        // Lru: 7 blocks through 3 lines, at most 3 there at the start, 3 loads a round.
        assert_eq!(
            policy(2, 0, CacheMap::Lru, 3, 16).fault_round_bound(&looked_up),
            2
        );
        assert_eq!(
            policy(2, 0, CacheMap::Lru, 7, 16).fault_round_bound(&looked_up),
            0
        );
        // One block a line: it may be there already.
        let mut one = vec![false; 16];
        one[3] = true;
        one[5] = true;
        assert_eq!(
            policy(2, 0, CacheMap::Demarle, 3, 16).fault_round_bound(&one),
            0
        );
        assert_eq!(
            policy(2, 0, CacheMap::Demarle, 3, 16).fault_round_bound(&[]),
            0
        );
    }

    #[test]
    fn a_single_line_cache_makes_progress_every_round() {
        // However the faults arrive, each round loads one block, and a block once loaded is
        // found at its row until evicted: every wanted block is eventually resident.
        let mut p = policy(4, 2, CacheMap::Demarle, 1, 64);
        let mut wanted: Vec<u32> = (0..64).filter(|k| !p.ranks().resident(*k)).collect();
        let mut rounds = 0;
        while let Some(&k) = wanted.first() {
            // The round used the line, as a ray would have used the block loaded last round.
            p.mark_used(&[1], &[1]);
            let plan = p.plan_round(&wanted, &[wanted.len() as u32]);
            assert_eq!(plan.loads.len(), 1);
            assert_eq!(plan.loads[0].block, k);
            assert_eq!(p.block_rows()[k as usize], p.cache_row());
            wanted.remove(0);
            rounds += 1;
        }
        assert_eq!(rounds, 47); // 64 blocks less 16 owned and the root
    }

    #[test]
    fn loads_use_the_mapping_of_the_rank() {
        for map in [CacheMap::Ize, CacheMap::Demarle] {
            let mut p = policy(3, 1, map, 4, 40);
            let faults = [2, 5, 9, 14];
            let plan = p.plan_round(&faults, &[0; 4]);
            for f in &plan.faults {
                assert_eq!(f.line, cache_line(map, p.ranks(), 4, f.block), "{map:?}");
            }
            for l in &plan.loads {
                assert_eq!(l.row, p.cache_row() + l.line);
                assert_eq!(p.tag(l.line), Some(l.block));
            }
        }
        // Ize numbers rank 1's borrowed blocks 0, 2, 3, 5, 6 densely: 2, 3, 5, 6 take lines
        // 1, 2, 3 and 0 (DeMarle: 2, 3, 1, 2, so 6 loses line 2 to 2).
        let mut p = policy(3, 1, CacheMap::Ize, 4, 40);
        let plan = p.plan_round(&[2, 3, 5, 6], &[0; 4]);
        let lines: Vec<u32> = plan.loads.iter().map(|l| l.line).collect();
        assert_eq!(lines, vec![1, 2, 3, 0]);
        let mut p = policy(3, 1, CacheMap::Demarle, 4, 40);
        let plan = p.plan_round(&[2, 3, 5, 6], &[0; 4]);
        let lines: Vec<u32> = plan.loads.iter().map(|l| l.line).collect();
        assert_eq!(lines, vec![2, 3, 1]);
    }

    #[test]
    fn lru_takes_the_least_recently_loaded_lines_one_fault_each() {
        // Rank 0 of 2, 3 lines. Round 1 fills lines 0, 1 in fault order.
        let mut p = policy(2, 0, CacheMap::Lru, 3, 40);
        let first = p.plan_round(&[5, 7], &[0; 3]);
        let lines: Vec<u32> = first.loads.iter().map(|l| l.line).collect();
        assert_eq!(lines, vec![0, 1]);
        // Round 2: the empty line 2 first, then line 0 (loaded before line 1), then line 1; the
        // fourth fault finds no line left and faults again.
        let second = p.plan_round(&[3, 9, 15, 21], &[0; 3]);
        let lines: Vec<u32> = second.loads.iter().map(|l| l.line).collect();
        assert_eq!(lines, vec![2, 0, 1]);
        let served: Vec<bool> = second.faults.iter().map(|f| f.served).collect();
        assert_eq!(served, vec![true, true, true, false]);
        let evicted: Vec<Option<u32>> = second.faults.iter().map(|f| f.evicted).collect();
        assert_eq!(evicted, vec![None, Some(5), Some(7), None]);
        assert_eq!(p.block_rows()[5], NONE);
        assert_eq!(p.block_rows()[21], NONE);
        // 3, 9 and 15 share DeMarle's line 0 of 3 (and Ize's line 1): held at once here.
        for k in [3, 9, 15] {
            assert_ne!(p.block_rows()[k], NONE, "block {k}");
        }
    }

    #[test]
    fn lru_keeps_the_lines_rays_used() {
        // Lines 0 and 1 loaded in round 1; in round 2 the GPU found its block in line 0 only, so
        // line 1 goes first although line 0 was loaded no later.
        let mut p = policy(2, 0, CacheMap::Lru, 2, 40);
        p.plan_round(&[5, 7], &[0; 2]);
        p.mark_used(&[1, 0], &[0, 0]);
        let plan = p.plan_round(&[9], &[0; 2]);
        assert_eq!(plan.loads[0].line, 1);
        assert_eq!(plan.faults[0].evicted, Some(7));
        assert_ne!(p.block_rows()[5], NONE);
        // Direct mappings take no notice.
        let mut p = policy(2, 0, CacheMap::Demarle, 2, 40);
        p.plan_round(&[5, 7], &[0; 2]);
        p.mark_used(&[1, 0], &[0, 0]);
        assert_eq!(p.plan_round(&[9], &[0; 2]).loads[0].line, 1);
    }

    #[test]
    fn lru_evicts_no_kept_line_while_others_are_free() {
        // 3 lines filled in round 1; in round 2 rays that stay live used lines 0 and 2. Of
        // round 3's three faults one goes to line 1; the other two fault again, although lines
        // 0 and 2 were loaded as early as line 1.
        let mut p = policy(2, 0, CacheMap::Lru, 3, 40);
        p.plan_round(&[5, 7, 9], &[0; 3]);
        p.mark_used(&[1, 0, 1], &[1, 0, 1]);
        let plan = p.plan_round(&[11, 13, 15], &[0; 3]);
        assert_eq!(plan.loads.len(), 1);
        assert_eq!((plan.loads[0].block, plan.loads[0].line), (11, 1));
        let served: Vec<bool> = plan.faults.iter().map(|f| f.served).collect();
        assert_eq!(served, vec![true, false, false]);
        for k in [5, 9, 11] {
            assert_ne!(p.block_rows()[k], NONE, "block {k}");
        }
        // A round that used every line still loads one block: the least recently loaded line.
        p.mark_used(&[1, 1, 1], &[1, 1, 1]);
        let plan = p.plan_round(&[13, 15], &[0; 3]);
        assert_eq!(plan.loads.len(), 1);
        assert_eq!(plan.faults[0].evicted, Some(5));
    }

    #[test]
    fn lru_keeps_every_node_block_the_round_used() {
        // Rank 0 of 2, blocks 0..8 node blocks: 5 and 7 (lines 0, 1) are node blocks, 9 (line 2)
        // a triangle block. The round used all three but kept none: only line 2 is free.
        let ranks = Ranks::new(2, 0).unwrap();
        let mut p = CachePolicy::new(ranks, CacheMap::Lru, 3, 40, 8);
        p.plan_round(&[5, 7, 9], &[0; 3]);
        p.mark_used(&[1, 1, 1], &[0, 0, 0]);
        let plan = p.plan_round(&[11, 13], &[0; 3]);
        assert_eq!(plan.loads.len(), 1);
        assert_eq!((plan.loads[0].block, plan.loads[0].line), (11, 2));
        // Unused, a node block's line is as free as any.
        p.mark_used(&[0, 0, 1], &[0, 0, 0]);
        let plan = p.plan_round(&[13, 15], &[0; 3]);
        let lines: Vec<u32> = plan.loads.iter().map(|l| l.line).collect();
        assert_eq!(lines, vec![0, 1]);
    }

    #[test]
    fn lru_evicts_a_used_line_no_live_ray_kept() {
        // Round 2 used lines 0 and 2, but only a ray still live kept line 2: line 0's rays are
        // done with it. Round 3's faults take line 1 (least recent) and line 0; line 2 stays.
        let mut p = policy(2, 0, CacheMap::Lru, 3, 40);
        p.plan_round(&[5, 7, 9], &[0; 3]);
        p.mark_used(&[1, 0, 1], &[0, 0, 1]);
        let plan = p.plan_round(&[11, 13, 15], &[0; 3]);
        let lines: Vec<u32> = plan.loads.iter().map(|l| l.line).collect();
        assert_eq!(lines, vec![1, 0]);
        assert_ne!(p.block_rows()[9], NONE);
        assert_eq!(p.block_rows()[15], NONE);
    }

    #[test]
    fn a_single_line_lru_cache_makes_progress_every_round() {
        let mut p = policy(3, 1, CacheMap::Lru, 1, 30);
        let mut wanted: Vec<u32> = (0..30).filter(|k| !p.ranks().resident(*k)).collect();
        while let Some(&k) = wanted.first() {
            // The round used the line, as a ray would have used the block loaded last round.
            p.mark_used(&[1], &[1]);
            let plan = p.plan_round(&wanted, &[wanted.len() as u32]);
            assert_eq!(plan.loads.len(), 1);
            assert_eq!(plan.loads[0].block, k);
            assert_eq!(p.block_rows()[k as usize], p.cache_row());
            assert_eq!(plan.faults.iter().filter(|f| f.served).count(), 1);
            wanted.remove(0);
        }
    }

    #[test]
    fn eviction_clears_the_old_block_row() {
        // DeMarle, 2 lines: blocks 3 and 5 share line 1.
        let mut p = policy(2, 0, CacheMap::Demarle, 2, 10);
        let row = p.cache_row() + 1;
        let first = p.plan_round(&[3], &[0, 1]);
        assert_eq!(first.faults[0].evicted, None);
        assert_eq!(p.block_rows()[3], row);
        let second = p.plan_round(&[5], &[0, 2]);
        assert_eq!(second.faults[0].evicted, Some(3));
        assert_eq!(second.faults[0].waiting, 2);
        assert_eq!(second.rows, vec![(3, NONE), (5, row)]);
        assert_eq!(p.block_rows()[3], NONE);
        assert_eq!(p.block_rows()[5], row);
        // Resident blocks are never touched.
        assert_eq!(p.block_rows()[0], 0);
        assert_eq!(p.block_rows()[4], 2);
    }

    #[test]
    fn fetch_ahead_loads_a_served_node_blocks_absent_children_into_lines_no_round_needs() {
        // Rank 0 of 2, 6 lines, 20 blocks of which 0..4 are node blocks: rank 0 owns the even
        // ones, block 0 is the root. Node block 1 leads to 3, 5, 6 (owned), 7 and 9.
        let ranks = Ranks::new(2, 0).unwrap();
        let new = |lines| {
            let mut p = CachePolicy::new(ranks, CacheMap::Lru, lines, 20, 4).with_fetch_ahead(true);
            assert!(p.wants_children(1));
            p.learn_children(1, vec![3, 5, 6, 7, 9]).unwrap();
            assert!(!p.wants_children(1));
            p
        };
        let mut p = new(6);
        let plan = p.plan_round(&[1], &[0; 6]);
        let loads: Vec<(u32, u32)> = plan.loads.iter().map(|l| (l.block, l.line)).collect();
        assert_eq!(loads, vec![(1, 0), (3, 1), (5, 2), (7, 3), (9, 4)]);
        assert_eq!(plan.ahead, 4);
        assert_eq!(plan.faults.len(), 1, "fetched ahead, not faulted");
        for k in [1, 3, 5, 7, 9] {
            assert_ne!(p.block_rows()[k as usize], NONE, "block {k}");
        }
        // A line the last round used (4) and one a live ray keeps (5) take nothing fetched
        // ahead, nor does the line the fault takes: 9 finds no line.
        let mut p = new(6);
        p.mark_used(&[0, 0, 0, 0, 1, 0], &[0, 0, 0, 0, 0, 1]);
        let plan = p.plan_round(&[1], &[0; 6]);
        let loads: Vec<(u32, u32)> = plan.loads.iter().map(|l| (l.block, l.line)).collect();
        assert_eq!(loads, vec![(1, 0), (3, 1), (5, 2), (7, 3)]);
        assert_eq!(p.block_rows()[9], NONE);
        // The lines run out before the children: only the served node block's children go.
        let mut p = new(2);
        let plan = p.plan_round(&[1], &[0; 2]);
        assert_eq!(plan.loads.len(), 2);
        assert_eq!((plan.loads[1].block, plan.ahead), (3, 1));
        // Off, or with a direct mapping, only the fault is loaded.
        for map in [CacheMap::Lru, CacheMap::Ize, CacheMap::Demarle] {
            let mut p =
                CachePolicy::new(ranks, map, 6, 20, 4).with_fetch_ahead(map != CacheMap::Lru);
            p.learn_children(1, vec![3, 5, 7, 9]).unwrap();
            let plan = p.plan_round(&[1], &[0; 6]);
            assert_eq!((plan.loads.len(), plan.ahead), (1, 0), "{map:?}");
        }
        // A block that names a block past the model is refused, naming both, and nothing is
        // learnt from it.
        let mut p = new(6);
        let e = p.learn_children(3, vec![5, 20]).unwrap_err().to_string();
        assert!(e.contains("node block 3") && e.contains("block 20"), "{e}");
        assert!(p.wants_children(3));
    }
}
