//! The training losses, and the recomposition both phases score.

use crate::features::EPSILON;
use crate::model::{ModelError, Specular};
use candle_core::Tensor;

/// L1 loss, the mean absolute difference.
pub fn l1(a: &Tensor, b: &Tensor) -> Result<Tensor, ModelError> {
    Ok((a - b)?.abs()?.mean_all()?)
}

/// Relative squared error `(x − y)² / (sg(x)² + 0.01)`, the training form of relMSE: the
/// denominator is the prediction with its gradient stopped, so the loss is minimised by the
/// mean of the plausible references, not by a value biased dark (as with y² in the
/// denominator) or by their median (as with L1).
pub fn relative_l2(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    relative_to(x, y, &x.detach())
}

/// `(x − y)² / (d² + 0.01)`, averaged: the relative squared error with denominator `d`.
fn relative_to(x: &Tensor, y: &Tensor, d: &Tensor) -> Result<Tensor, ModelError> {
    Ok(((x - y)?.sqr()? / (d.sqr()? + 0.01)?)?.mean_all()?)
}

/// Relative squared error `(x − y)² / (y² + 0.01)` with the reference as its denominator:
/// the relMSE the evaluator reports, so a too-bright blotch on a dark background costs what
/// it costs there (with the prediction as denominator it costs `(y² + 0.01) / (x² + 0.01)`
/// of that). Pulled dark by noise in `y` (the test below): for clean references only.
pub fn relmse(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    relative_to(x, y, y)
}

/// Relative squared error `(x − y)² / (min(sg(x), y)² + 0.01)`: each error charged at
/// least what the evaluator charges ([`relmse`]) and what the prediction's denominator
/// charges ([`relative_l2`]): a bright blotch on a dark background by the reference, light
/// missing from a bright pixel by the prediction, so noise in `y` pulls it neither way much.
pub fn relative_smaller(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    relative_to(x, y, &x.detach().minimum(y)?)
}

/// Relative squared error `(x − y)² / (m² + 0.01)`, `m` the 5×5 box mean of the reference
/// around each pixel (over the pixels inside the patch): a bright blotch or a kept firefly
/// on a dark background costs about what the evaluator charges ([`relmse`]), so the network
/// is not paid to leave sparse noise in place as with the prediction's denominator
/// ([`relative_l2`]), while a pixel's own noise is a 25th of its denominator, so noisy
/// references pull it only slightly dark (the test below). Plus the same error of the 8×8
/// block means against the reference's: softmax kernels are never exactly one tap, and with
/// a reference's denominator light leaking into a dark neighbour costs far more than light
/// lost from a bright pixel, so without it the network learns to erode bright regions (a
/// simulator `cornell` frame lost 7 % of its light). Takes `(N, C, H, W)` tensors.
pub fn relmse_local(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    plus_block_means(relative_to(x, y, &local_mean(y)?)?, x, y)
}

/// Relative squared error `(x − y)² / (m² + 0.01)`, `m` the 5×5 box mean of the
/// prediction with its gradient stopped, plus the relMSE of 8×8 block means: mean-seeking
/// like [`relative_l2`] (no reference in the denominator, whose minimiser under
/// uncertainty is biased dark), but a spike kept in place is charged by its neighbourhood's
/// mean, not by itself. Takes `(N, C, H, W)` tensors.
pub fn relative_local(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    plus_block_means(relative_to(x, y, &local_mean(&x.detach())?)?, x, y)
}

/// The 5×5 box mean of `v` around each pixel, over the pixels inside the patch.
fn local_mean(v: &Tensor) -> Result<Tensor, ModelError> {
    let (_, c, _, _) = v.dims4()?;
    let k = Tensor::ones((c, 1, 5, 5), v.dtype(), v.device())?;
    let sum = v.conv2d(&k, 2, 1, 1, c)?;
    let count = v.ones_like()?.conv2d(&k, 2, 1, 1, c)?;
    Ok((sum / count)?)
}

/// [`relmse`] plus the relMSE of 8×8 block means, as [`relmse_local`] adds it: each
/// pixel's error charged by its own reference, as the evaluator charges it (light leaking
/// into a dark pixel of a fine texture costs what it costs there, where the local mean's
/// denominator made it cheap), and light lost from a block charged too. On the specular
/// branch it keeps fine texture but darkens bright regions as `relmse` does: the block
/// term does not stop it (BENCHMARKS.md). Takes `(N, C, H, W)` tensors.
pub fn relmse_blocks(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    plus_block_means(relmse(x, y)?, x, y)
}

/// [`relmse`] plus each 8×8 block mean's relative L2 error with the prediction's block
/// mean (gradient stopped) as denominator: every pixel charged as the evaluator charges it
/// (kept fireflies, light leaked into a dark texel), and light lost from a block charged by
/// what is left of it, so dropping a whole bright region costs far more than keeping it
/// (the block term of [`relmse_blocks`] caps that cost at 1), and the block means seek the
/// mean of the plausible references rather than a darker value. Takes `(N, C, H, W)` tensors.
pub fn relmse_light(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    relmse_light_weighted(x, y, 1.0)
}

/// [`relmse_light`] with its block term weighted `weight` (`kpcn train --block-weight`):
/// at 64 (8 × 8) a block's error counts as much as each of its pixels' errors would.
pub fn relmse_light_weighted(x: &Tensor, y: &Tensor, weight: f64) -> Result<Tensor, ModelError> {
    let pixels = relmse(x, y)?;
    let (_, _, h, w) = y.dims4()?;
    if h < BLOCK || w < BLOCK {
        return Ok(pixels);
    }
    let (bx, by) = (x.avg_pool2d(BLOCK)?, y.avg_pool2d(BLOCK)?);
    Ok((pixels + (relative_l2(&bx, &by)? * weight)?)?)
}

/// `pixels` plus the relMSE of the `BLOCK`×`BLOCK` means of `x` against `y`'s (when the
/// patch holds one).
fn plus_block_means(pixels: Tensor, x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    let (_, _, h, w) = y.dims4()?;
    if h < BLOCK || w < BLOCK {
        return Ok(pixels);
    }
    let (bx, by) = (x.avg_pool2d(BLOCK)?, y.avg_pool2d(BLOCK)?);
    Ok((pixels + relative_to(&bx, &by, &by)?)?)
}

/// The block whose mean [`relmse_local`] keeps.
const BLOCK: usize = 8;

/// L1 between tonemapped radiances, ln(1 + max(v, 0)): keeps the shadows' and the
/// highlights' shapes in view where the relative term is flat.
pub fn tonemapped_l1(x: &Tensor, y: &Tensor) -> Result<Tensor, ModelError> {
    let t = |v: &Tensor| -> Result<Tensor, ModelError> { Ok((v.relu()? + 1.0)?.log()?) };
    l1(&t(x)?, &t(y)?)
}

/// Where the loss charges errors (`kpcn train --loss-scale`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum LossScale {
    /// At the scale the network sees (autoexposed, with `--exposure auto`).
    #[default]
    Exposed,
    /// At the radiance the renderer wrote: each patch's prediction and target divided by
    /// its frame's exposure first, as the evaluator charges them. The same as `exposed`
    /// for raw radiance.
    Rendered,
}

/// The training loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Loss {
    /// Bako et al.: L1 on each branch's transformed target (irradiance, ln(1 + specular)),
    /// then L1 on the recomposed colour.
    #[default]
    L1,
    /// Relative L2 (the prediction, gradient stopped, as its denominator: it seeks the
    /// mean) plus L1 on tonemapped radiance, on the irradiance and the specular radiance in
    /// phase 1, on the recomposed colour in phase 2.
    Relative,
    /// `relative`'s relative L2 alone, without its L1 term on tonemapped radiance (on the
    /// specular branch, on the logs). That term seeks the median of the plausible
    /// references, which lies under their mean where bright light is sparse.
    RelativeL2,
    /// relMSE with the reference as its denominator (the evaluator's measure) plus L1 on
    /// tonemapped radiance, where `relative` has the prediction's: for data whose
    /// references are clean (biased dark on noisy ones).
    Relmse,
    /// relMSE with the smaller of the prediction (gradient stopped) and the reference as
    /// its denominator plus L1 on tonemapped radiance.
    RelativeSmaller,
    /// relMSE with the reference's 5×5 local mean as its denominator plus L1 on tonemapped
    /// radiance: charges kept noise as the evaluator does, nearly unbiased on noisy
    /// references. Trains a specular branch afresh where `relative` collapses it to one tap.
    RelmseLocal,
    /// relMSE with the reference as its denominator plus the relMSE of 8×8 block means,
    /// plus L1 on tonemapped radiance.
    RelmseBlocks,
    /// Relative L2 with the prediction's 5×5 local mean (gradient stopped) as its
    /// denominator plus the relMSE of 8×8 block means, plus L1 on tonemapped radiance.
    RelativeLocal,
    /// relMSE with the reference as its denominator plus the relative L2 of 8×8 block
    /// means with the prediction's block mean as denominator, plus L1 on tonemapped
    /// radiance: the evaluator's charge per pixel, and light lost from a block charged by
    /// what is left of it.
    RelmseLight,
}

/// A loss term of a prediction against its target.
type Term = fn(&Tensor, &Tensor) -> Result<Tensor, ModelError>;

impl Loss {
    /// The relative term, for the losses that have one.
    fn relative(self) -> Option<Term> {
        match self {
            Loss::L1 => None,
            Loss::Relative | Loss::RelativeL2 => Some(relative_l2),
            Loss::Relmse => Some(relmse),
            Loss::RelativeSmaller => Some(relative_smaller),
            Loss::RelmseLocal => Some(relmse_local),
            Loss::RelmseBlocks => Some(relmse_blocks),
            Loss::RelativeLocal => Some(relative_local),
            Loss::RelmseLight => Some(relmse_light),
        }
    }

    /// The relative term of `x` against `y`, for the losses that have one; `block_weight`
    /// weights `relmse-light`'s block term.
    fn relative_term(self, x: &Tensor, y: &Tensor, block_weight: f64) -> Result<Option<Tensor>, ModelError> {
        match (self, self.relative()) {
            (Loss::RelmseLight, _) => relmse_light_weighted(x, y, block_weight).map(Some),
            (_, Some(relative)) => relative(x, y).map(Some),
            (_, None) => Ok(None),
        }
    }

    /// Whether the loss adds an L1 term (on tonemapped radiance, or on the specular
    /// branch's logs) to its relative term.
    fn with_l1(self) -> bool {
        self != Loss::RelativeL2
    }

    /// The loss of a prediction of linear radiance (the irradiance, the colour). With
    /// `exposure` (each patch's, `[B, 1, 1, 1]`) `x` and `y` are first divided by it: the
    /// error charged at the radiance the renderer wrote, as the evaluator charges it, not at
    /// the scale the network sees ([`LossScale::Rendered`]).
    pub fn radiance(
        self,
        x: &Tensor,
        y: &Tensor,
        block_weight: f64,
        exposure: Option<&Tensor>,
    ) -> Result<Tensor, ModelError> {
        let (x, y) = as_rendered(x.clone(), y.clone(), exposure)?;
        match self.relative_term(&x, &y, block_weight)? {
            None => l1(&x, &y),
            Some(relative) if self.with_l1() => Ok((relative + tonemapped_l1(&x, &y)?)?),
            Some(relative) => Ok(relative),
        }
    }

    /// The loss of the specular branch's output `s_hat` against its target ln(1 + s); with
    /// `exposure` its relative term is charged at the radiance the renderer wrote, as in
    /// [`Loss::radiance`], and the L1 of the logs where the network works.
    pub fn specular(
        self,
        domain: Specular,
        s_hat: &Tensor,
        target_log: &Tensor,
        block_weight: f64,
        exposure: Option<&Tensor>,
    ) -> Result<Tensor, ModelError> {
        let log = || l1(&domain.log_tensor(s_hat)?, target_log);
        if self.relative().is_none() {
            return log();
        }
        let (radiance, target) = as_rendered(domain.radiance_tensor(s_hat)?, (target_log.exp()? - 1.0)?, exposure)?;
        match self.relative_term(&radiance, &target, block_weight)? {
            Some(relative) if self.with_l1() => Ok((relative + log()?)?),
            Some(relative) => Ok(relative),
            None => log(),
        }
    }
}

/// `x` and `y` divided by each patch's `exposure`, where one is given.
fn as_rendered(x: Tensor, y: Tensor, exposure: Option<&Tensor>) -> Result<(Tensor, Tensor), ModelError> {
    Ok(match exposure {
        Some(e) => (x.broadcast_div(e)?, y.broadcast_div(e)?),
        None => (x, y),
    })
}

/// Recomposed colour `(albedo + ε) ⊙ d̂` plus the specular radiance of `ŝ`
/// ([`Specular::radiance_tensor`]).
pub fn recompose(albedo: &Tensor, d_hat: &Tensor, s_hat: &Tensor, domain: Specular) -> Result<Tensor, ModelError> {
    let diffuse = ((albedo + EPSILON as f64)? * d_hat)?;
    Ok(diffuse.add(&domain.radiance_tensor(s_hat)?)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::scalar;
    use candle_core::{Device, Var};

    /// d loss / d x for a constant prediction `x` against samples `ys`.
    fn slope(loss: fn(&Tensor, &Tensor) -> Result<Tensor, ModelError>, x: f32, ys: &[f32]) -> f32 {
        // An image of 40 rows where the count allows, for the losses that look around a pixel.
        let n = ys.len();
        let shape = if n.is_multiple_of(40) { (1, 1, 40, n / 40) } else { (1, 1, 1, n) };
        let v = Var::from_tensor(&Tensor::full(x, shape, &Device::Cpu).unwrap()).unwrap();
        let y = Tensor::new(ys, &Device::Cpu).unwrap().reshape(shape).unwrap();
        let g = loss(v.as_tensor(), &y).unwrap().backward().unwrap();
        g.get(v.as_tensor()).unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap()
    }

    /// Where the loss's slope over `ys` crosses zero for a constant prediction (bisection:
    /// every loss here is convex in a constant prediction).
    fn converges_to(loss: fn(&Tensor, &Tensor) -> Result<Tensor, ModelError>, ys: &[f32]) -> f32 {
        let (mut lo, mut hi) = (0f32, ys.iter().fold(0f32, |a, &b| a.max(b)));
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if slope(loss, mid, ys) < 0.0 { lo = mid } else { hi = mid }
        }
        0.5 * (lo + hi)
    }

    /// Noisy targets as a renderer makes them (Noise2Noise, the corpus's 512-spp
    /// references): each the mean of `n` samples of a path that finds a light of
    /// radiance `1 / p` with probability `p` (else 0), so every target's expectation is 1.
    fn noisy_targets(n: usize, p: f64, count: usize) -> Vec<f32> {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut uniform = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..count).map(|_| ((0..n).filter(|_| uniform() < p).count() as f64 / (n as f64 * p)) as f32).collect()
    }

    #[test]
    fn on_noisy_targets_the_relative_loss_converges_to_their_expectation() {
        // With its denominator from the prediction the relative term converges to the
        // targets' mean, the clean value, however noisy they are; with the noisy target as
        // its denominator it is pulled below (measured: −7.5 % on 512-sample targets, to
        // 0.008 on 16-sample ones); with the targets' 5×5 mean (relmse_local), +0.2 % and
        // −8 %. The tonemapped L1 term pulls toward the targets' median: the whole loss
        // lands +0.2 % off on 512-sample targets, +2.8 % on 16.
        let full = |x: &Tensor, y: &Tensor| Loss::Relative.radiance(x, y, 1.0, None);
        for (n, full_bias, local_bias) in [(512, 0.01, 0.01), (16, 0.05, 0.15)] {
            let ys = noisy_targets(n, 0.05, 4000);
            let mean = ys.iter().map(|&v| v as f64).sum::<f64>() / ys.len() as f64;
            let relative = converges_to(relative_l2, &ys) as f64;
            assert!((relative / mean - 1.0).abs() < 1e-3, "{n} samples: relative L2 → {relative}, mean {mean}");
            let whole = converges_to(full, &ys) as f64;
            let biased = converges_to(relmse, &ys) as f64;
            println!(
                "{n} samples per target: mean {mean:.4}; relative L2 → {relative:.4}, whole loss → {whole:.4}, the target as denominator → {biased:.4}"
            );
            assert!((whole / mean - 1.0).abs() < full_bias, "{n} samples: the whole loss → {whole}, mean {mean}");
            assert!(biased < 0.95 * mean, "{n} samples: the target as denominator → {biased}, mean {mean}");
            let local = converges_to(relmse_local, &ys) as f64;
            println!("{n} samples per target: the targets' 5×5 mean as denominator → {local:.4}");
            assert!(
                (local / mean - 1.0).abs() < local_bias,
                "{n} samples: the local mean as denominator → {local}, mean {mean}"
            );
            let predicted = converges_to(relative_local, &ys) as f64;
            println!("{n} samples per target: the prediction's 5×5 mean as denominator → {predicted:.4}");
            assert!(
                (predicted / mean - 1.0).abs() < local_bias,
                "{n} samples: the prediction's local mean as denominator → {predicted}, mean {mean}"
            );
        }
    }

    #[test]
    fn without_the_l1_term_the_loss_seeks_the_mean_of_sparse_light() {
        // Where what the network cannot tell apart is mostly dark with rare bright hits (a
        // room lit through a slit, seen at 4 samples), the tonemapped L1 term pulls the
        // prediction toward the dark median, the more so the brighter the light (below 0.1
        // the relative term's floor of 0.01 makes it dominate); `relative-l2` lands on the
        // mean.
        // Measured: −2.4 / −6.5 / −11.1 % at means of 0.1 / 1 / 10.
        for (scale, dark) in [(0.1, 0.985), (1.0, 0.95), (10.0, 0.92)] {
            let ys: Vec<f32> = noisy_targets(4, 0.1, 4000).iter().map(|v| v * scale).collect();
            let mean = ys.iter().map(|&v| v as f64).sum::<f64>() / ys.len() as f64;
            let with_l1 = converges_to(|x, y| Loss::Relative.radiance(x, y, 1.0, None), &ys) as f64;
            let alone = converges_to(|x, y| Loss::RelativeL2.radiance(x, y, 1.0, None), &ys) as f64;
            println!("mean {mean:.4}: relative → {with_l1:.4}, relative-l2 → {alone:.4}");
            assert!((alone / mean - 1.0).abs() < 1e-3, "relative-l2 → {alone}, mean {mean}");
            assert!(with_l1 < dark * mean, "relative → {with_l1}, mean {mean}");
        }
    }

    #[test]
    fn relative_local_charges_a_kept_spike_by_its_neighbourhood() {
        // A flat dark reference; the prediction keeps one firefly. The prediction's own
        // value as denominator (relative L2) makes the spike nearly free.
        let image = |spike: f32| {
            let v: Vec<f32> = (0..64).map(|i| if i == 27 { spike } else { 0.1 }).collect();
            Tensor::new(v, &Device::Cpu).unwrap().reshape((1, 1, 8, 8)).unwrap()
        };
        let (x, y) = (image(10.0), image(0.1));
        let (own, local) =
            (scalar(&relative_l2(&x, &y).unwrap()).unwrap(), scalar(&relative_local(&x, &y).unwrap()).unwrap());
        assert!(local > 50.0 * own, "the prediction's local mean charges {local}, its own value {own}");
    }

    /// `loss` of a one-pixel prediction `x` against `y`.
    fn at(loss: Term, x: f32, y: f32) -> f32 {
        let t = |v: f32| Tensor::new(&[v], &Device::Cpu).unwrap();
        scalar(&loss(&t(x), &t(y)).unwrap()).unwrap()
    }

    #[test]
    fn relmse_charges_a_bright_blotch_on_a_dark_background_what_the_evaluator_does() {
        // Reference 0.08 (a shadow beside a sunlit floor), prediction 0.7 (light bled in).
        let evaluator = (0.7f32 - 0.08).powi(2) / (0.08f32.powi(2) + 0.01);
        assert!((at(relmse, 0.7, 0.08) / evaluator - 1.0).abs() < 1e-5);
        // The prediction as denominator charges 1/30 of it: such blotches are cheap to learn.
        let cheap = at(relative_l2, 0.7, 0.08);
        assert!(cheap * 25.0 < evaluator, "{cheap} against {evaluator}");
    }

    #[test]
    fn the_block_term_charges_light_lost_more_than_the_same_error_that_keeps_it() {
        // A bright 4×4 square on black: each bright pixel 0.3 too dark, or alternately 0.3
        // too dark and too bright. The same per-pixel errors; only the first loses light.
        let image = |f: &dyn Fn(usize, usize) -> f32| {
            let v: Vec<f32> = (0..64).map(|i| f(i / 8, i % 8)).collect();
            Tensor::new(v, &Device::Cpu).unwrap().reshape((1, 1, 8, 8)).unwrap()
        };
        let bright = |r: usize, c: usize| (2..6).contains(&r) && (2..6).contains(&c);
        let y = image(&|r, c| if bright(r, c) { 5.0 } else { 0.0 });
        let eroded = image(&|r, c| if bright(r, c) { 4.7 } else { 0.0 });
        let kept = image(&|r, c| if bright(r, c) { 5.0 + if (r + c) % 2 == 0 { 0.3 } else { -0.3 } } else { 0.0 });
        for (name, loss) in
            [("relmse-local", relmse_local as Term), ("relmse-blocks", relmse_blocks), ("relmse-light", relmse_light)]
        {
            let (lost, same) =
                (scalar(&loss(&eroded, &y).unwrap()).unwrap(), scalar(&loss(&kept, &y).unwrap()).unwrap());
            assert!(lost > 1.2 * same, "{name}: light lost {lost}, light kept {same}");
        }
        // `relmse` alone charges both the same.
        let (lost, same) =
            (scalar(&relmse(&eroded, &y).unwrap()).unwrap(), scalar(&relmse(&kept, &y).unwrap()).unwrap());
        assert!((lost / same - 1.0).abs() < 1e-4, "relmse: light lost {lost}, light kept {same}");
    }

    #[test]
    fn relmse_blocks_charges_light_leaked_into_a_dark_texel_as_the_evaluator_does() {
        // A fine texture (bright and dark pixels alternating) blurred to its mean: the local
        // mean's denominator charges the dark pixels' error by the bright ones' light.
        let image = |f: &dyn Fn(usize) -> f32| {
            let v: Vec<f32> = (0..64).map(f).collect();
            Tensor::new(v, &Device::Cpu).unwrap().reshape((1, 1, 8, 8)).unwrap()
        };
        let y = image(&|i| if (i / 8 + i % 8) % 2 == 0 { 2.0 } else { 0.05 });
        let blurred = image(&|_| 1.025);
        let ratio = |loss: Term| {
            scalar(&loss(&blurred, &y).unwrap()).unwrap() / scalar(&relmse(&blurred, &y).unwrap()).unwrap()
        };
        assert!(ratio(relmse_local) < 0.3, "relmse-local charges {}× relmse", ratio(relmse_local));
        assert!(ratio(relmse_blocks) >= 1.0, "relmse-blocks charges {}× relmse", ratio(relmse_blocks));
    }

    #[test]
    fn relmse_light_charges_a_dropped_bright_block_more_than_a_kept_one() {
        // A bright 8×8 block on a dark patch: dropped to the background, or kept 130 % too
        // bright. relmse-blocks charges both blocks at most 1 (its denominator is the
        // reference's block mean) and so prefers dropping; relmse-light charges the drop by
        // what is left of the block.
        let image = |v: f32| {
            let p: Vec<f32> = (0..256).map(|i| if i % 16 < 8 && i / 16 < 8 { v } else { 0.05 }).collect();
            Tensor::new(p, &Device::Cpu).unwrap().reshape((1, 1, 16, 16)).unwrap()
        };
        let (y, dropped, kept) = (image(3.0), image(0.05), image(7.0));
        let cost = |loss: Term, x: &Tensor| scalar(&loss(x, &y).unwrap()).unwrap();
        assert!(cost(relmse_blocks, &dropped) < cost(relmse_blocks, &kept), "relmse-blocks prefers dropping");
        let (drop, keep) = (cost(relmse_light, &dropped), cost(relmse_light, &kept));
        assert!(drop > 10.0 * keep, "relmse-light: dropped {drop}, kept {keep}");
    }

    #[test]
    fn as_rendered_a_brightened_patch_costs_what_it_cost_before_brightening() {
        // Two patches, brightened 8× and darkened 2× by autoexposure: charged as rendered,
        // their errors cost what the unexposed patches' do, in both branches' terms;
        // charged as exposed they cost otherwise (relMSE's 0.01 in the denominator weighs
        // less beside brightened values, more beside darkened ones).
        let dev = &Device::Cpu;
        let rendered_y: Vec<f32> = (0..128).map(|i| 0.02 + 0.05 * (i % 7) as f32).collect();
        let rendered_x: Vec<f32> =
            rendered_y.iter().enumerate().map(|(i, v)| v * (0.6 + 0.1 * (i % 5) as f32)).collect();
        let e = Tensor::new(&[8f32, 0.5], dev).unwrap().reshape((2, 1, 1, 1)).unwrap();
        let image = |v: &[f32]| Tensor::new(v, dev).unwrap().reshape((2, 1, 8, 8)).unwrap();
        let (x, y) = (image(&rendered_x), image(&rendered_y));
        let (ex, ey) = (x.broadcast_mul(&e).unwrap(), y.broadcast_mul(&e).unwrap());
        for loss in [Loss::L1, Loss::Relative, Loss::RelmseLocal, Loss::RelmseLight] {
            let plain = scalar(&loss.radiance(&x, &y, 1.0, None).unwrap()).unwrap();
            let rendered = scalar(&loss.radiance(&ex, &ey, 1.0, Some(&e)).unwrap()).unwrap();
            assert!((rendered / plain - 1.0).abs() < 1e-5, "{loss:?}: {rendered} against {plain}");
            let exposed = scalar(&loss.radiance(&ex, &ey, 1.0, None).unwrap()).unwrap();
            assert!((exposed / plain - 1.0).abs() > 0.05, "{loss:?}: exposure did not matter");
            // The specular branch's loss on ŝ = ln(1 + s): only its relative term moves to
            // the rendered scale; the L1 of the logs stays where the network works.
            let domain = Specular::Log;
            let (log_ex, log_ey) =
                ((ex.clone() + 1.0).unwrap().log().unwrap(), (ey.clone() + 1.0).unwrap().log().unwrap());
            let specular = scalar(&loss.specular(domain, &log_ex, &log_ey, 1.0, Some(&e)).unwrap()).unwrap();
            let relative =
                if loss == Loss::L1 { 0.0 } else { plain - scalar(&tonemapped_l1(&x, &y).unwrap()).unwrap() };
            let log_l1 = scalar(&l1(&log_ex, &log_ey).unwrap()).unwrap();
            assert!((specular - log_l1 - relative).abs() < 1e-5 * (log_l1 + relative), "{loss:?} specular: {specular}");
        }
    }

    #[test]
    fn the_block_weight_scales_only_relmse_light_block_term() {
        // A bright 8×8 block dropped: the block term is what relmse-light adds to relmse,
        // and --block-weight multiplies exactly that; other losses ignore it.
        let p: Vec<f32> = (0..256).map(|i| if i % 16 < 8 && i / 16 < 8 { 3.0 } else { 0.05 }).collect();
        let y = Tensor::new(p, &Device::Cpu).unwrap().reshape((1, 1, 16, 16)).unwrap();
        let x = Tensor::full(0.05f32, (1, 1, 16, 16), &Device::Cpu).unwrap();
        let cost = |loss: Loss, w: f64| scalar(&loss.radiance(&x, &y, w, None).unwrap()).unwrap();
        let block = scalar(&relmse_light(&x, &y).unwrap()).unwrap() - scalar(&relmse(&x, &y).unwrap()).unwrap();
        assert!(block > 0.1, "the dropped block costs {block}");
        let added = cost(Loss::RelmseLight, 64.0) - cost(Loss::RelmseLight, 1.0);
        assert!((added / (63.0 * block) - 1.0).abs() < 1e-4, "added {added}, block term {block}");
        assert_eq!(cost(Loss::RelmseBlocks, 64.0), cost(Loss::RelmseBlocks, 1.0));
    }

    #[test]
    fn relative_smaller_charges_each_error_at_least_what_both_others_do() {
        // Too bright on a dark reference, then light missing from a bright one.
        for (x, y) in [(0.7, 0.08), (0.08, 0.7)] {
            let smaller = at(relative_smaller, x, y);
            let most = at(relmse, x, y).max(at(relative_l2, x, y));
            assert!((smaller / most - 1.0).abs() < 1e-5, "x {x}, y {y}: {smaller} against {most}");
        }
    }

    #[test]
    fn relative_loss_seeks_the_mean_where_l1_seeks_the_median() {
        // Skewed plausible references, as where a rare bright sample may or may not be real.
        let ys = [0.1f32, 0.1, 0.1, 2.0];
        let mean = ys.iter().sum::<f32>() / 4.0;
        assert!(slope(relative_l2, mean, &ys).abs() < 1e-6, "stationary at the mean");
        assert!(slope(relative_l2, 0.1, &ys) < 0.0, "below the mean it pushes up");
        assert!(slope(relative_l2, 1.0, &ys) > 0.0);
        // L1's slope is already zero-or-positive just above the median: it keeps the dark value.
        assert!(slope(l1, 0.11, &ys) > 0.0);
        // The tonemapped term is finite on negative and huge values.
        let t = tonemapped_l1(
            &Tensor::new(&[-1f32, 1e30], &Device::Cpu).unwrap(),
            &Tensor::new(&[0f32, 1.0], &Device::Cpu).unwrap(),
        );
        assert!(scalar(&t.unwrap()).unwrap().is_finite());
    }
}
