//! [`FallbackEngine`]: the GPU engine, replaced by the CPU engine for the rest of the run when
//! the GPU device is lost.

use super::cpu::CpuEngine;
use super::{
    ColourHistogram, ContrastTable, FrameInput, LikelihoodEngine, LikelihoodError,
    LikelihoodParams, Particle, TermLogs,
};

/// Wraps an engine (the GPU's) so that a lost device does not end the run: on the first
/// [`LikelihoodError::DeviceLost`] it opens the CPU engine on all threads, gives it the colour
/// model and contrast table it was given, repeats the failed call there and stays on the CPU from then on, with a
/// one-line notice for the caller to print ([`LikelihoodEngine::take_notice`]). Every other
/// error is passed through unchanged.
///
/// The results after the switch are the CPU engine's, which agree with the GPU's to the
/// tolerances stated in `tests/gpu.rs` (about 1e-5 in a log-likelihood), not bit for bit.
pub struct FallbackEngine {
    active: Box<dyn LikelihoodEngine + Send>,
    on_cpu: bool,
    model: Option<ColourHistogram>,
    contrast: Option<ContrastTable>,
    notice: Option<String>,
}

impl std::fmt::Debug for FallbackEngine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FallbackEngine")
            .field("active", &self.active.name())
            .field("on_cpu", &self.on_cpu)
            .finish_non_exhaustive()
    }
}

impl FallbackEngine {
    /// Wraps `primary`.
    pub fn new(primary: Box<dyn LikelihoodEngine + Send>) -> Self {
        Self {
            active: primary,
            on_cpu: false,
            model: None,
            contrast: None,
            notice: None,
        }
    }

    /// Whether the engine has switched to the CPU.
    pub fn fell_back(&self) -> bool {
        self.on_cpu
    }

    /// What a setter's result `r` means here: on success `keep` records the value for the
    /// CPU engine a fall-back opens. On a lost device the engine falls back and `retry` sets
    /// the value on the CPU engine, which checks it (a lost GPU engine reports the loss before
    /// looking at the value): only a value it takes is recorded, and a refused one is the
    /// error, the earlier value kept, as on any engine. Any other error passes through and
    /// nothing is recorded.
    fn settle(
        &mut self,
        r: Result<(), LikelihoodError>,
        retry: impl FnOnce(&mut dyn LikelihoodEngine) -> Result<(), LikelihoodError>,
        keep: impl FnOnce(&mut Self),
    ) -> Result<(), LikelihoodError> {
        match r {
            Err(LikelihoodError::DeviceLost(msg)) if !self.on_cpu => {
                self.fall_back(&msg)?;
                retry(self.active.as_mut())?;
                keep(self);
                Ok(())
            }
            Ok(()) => {
                keep(self);
                Ok(())
            }
            Err(e) => Err(e),
        }
    }

    fn fall_back(&mut self, lost: &str) -> Result<(), LikelihoodError> {
        let from = self.active.name();
        let mut cpu = CpuEngine::new();
        if let Some(m) = &self.model {
            cpu.set_colour_model(m)?;
        }
        if let Some(t) = &self.contrast {
            cpu.set_contrast_table(t)?;
        }
        self.active = Box::new(cpu);
        self.on_cpu = true;
        self.notice = Some(format!(
            "note: GPU device lost ({lost}) on {from}; likelihood on the CPU for the rest of the run"
        ));
        Ok(())
    }
}

impl LikelihoodEngine for FallbackEngine {
    fn name(&self) -> String {
        if self.on_cpu {
            format!("{} (after the GPU device was lost)", self.active.name())
        } else {
            self.active.name()
        }
    }

    fn set_colour_model(&mut self, model: &ColourHistogram) -> Result<(), LikelihoodError> {
        let r = self.active.set_colour_model(model);
        self.settle(
            r,
            |e| e.set_colour_model(model),
            |s| s.model = Some(model.clone()),
        )
    }

    fn set_contrast_table(&mut self, table: &ContrastTable) -> Result<(), LikelihoodError> {
        let r = self.active.set_contrast_table(table);
        self.settle(
            r,
            |e| e.set_contrast_table(table),
            |s| s.contrast = Some(table.clone()),
        )
    }

    fn evaluate(
        &mut self,
        frame: &FrameInput<'_>,
        params: &LikelihoodParams,
        particles: &[Particle],
        out: &mut Vec<TermLogs>,
    ) -> Result<(), LikelihoodError> {
        match self.active.evaluate(frame, params, particles, out) {
            Err(LikelihoodError::DeviceLost(msg)) if !self.on_cpu => {
                self.fall_back(&msg)?;
                self.active.evaluate(frame, params, particles, out)
            }
            r => r,
        }
    }

    fn take_notice(&mut self) -> Option<String> {
        self.notice.take()
    }

    fn runs_on_calling_pool(&self) -> bool {
        self.active.runs_on_calling_pool()
    }

    fn check_capacity(
        &self,
        particles: usize,
        width: u32,
        height: u32,
        params: &LikelihoodParams,
    ) -> Result<(), LikelihoodError> {
        self.active.check_capacity(particles, width, height, params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::likelihood::HIST_BINS;

    /// An engine that works `ok_calls` times, then reports a lost device.
    struct Flaky {
        ok_calls: usize,
    }

    impl LikelihoodEngine for Flaky {
        fn name(&self) -> String {
            "flaky (Vulkan)".into()
        }
        fn set_colour_model(&mut self, _: &ColourHistogram) -> Result<(), LikelihoodError> {
            Ok(())
        }
        fn set_contrast_table(&mut self, _: &ContrastTable) -> Result<(), LikelihoodError> {
            Ok(())
        }
        fn evaluate(
            &mut self,
            _: &FrameInput<'_>,
            _: &LikelihoodParams,
            particles: &[Particle],
            out: &mut Vec<TermLogs>,
        ) -> Result<(), LikelihoodError> {
            if self.ok_calls == 0 {
                return Err(LikelihoodError::DeviceLost("Destroyed: test".into()));
            }
            self.ok_calls -= 1;
            out.clear();
            out.resize(particles.len(), TermLogs::default());
            Ok(())
        }
    }

    /// The one bin of the tests' red frame.
    fn red_model() -> ColourHistogram {
        let mut model = vec![0.0; HIST_BINS];
        model[6 * 64 + 8 + 1] = 1.0;
        ColourHistogram(model)
    }

    /// A frame of `img` whose previous estimate is a small ellipse in its middle.
    fn red_frame(img: &image::RgbImage) -> FrameInput<'_> {
        FrameInput {
            image: img,
            features: &[],
            depths: None,
            prev: Particle {
                cx: 16.0,
                cy: 12.0,
                a: 5.0,
                b: 6.0,
                ..Default::default()
            },
            theta0: 0.0,
        }
    }

    #[test]
    fn a_lost_device_switches_to_the_cpu_once_with_one_notice() {
        let img = image::RgbImage::from_pixel(32, 24, image::Rgb([200, 40, 40]));
        let model = red_model();
        let frame = red_frame(&img);
        // With the contrast term on, so the CPU engine also needs the table given before.
        let params = LikelihoodParams {
            terms: crate::likelihood::TERM_ALL,
            contrast_scale: 0.01,
            ..Default::default()
        };
        let table =
            ContrastTable::from_histograms(&model, &ColourHistogram(vec![1.0 / 512.0; 512]), 3.0)
                .unwrap();
        let ps = [
            frame.prev,
            Particle {
                cx: 3.0,
                ..frame.prev
            },
        ];
        let mut e = FallbackEngine::new(Box::new(Flaky { ok_calls: 1 }));
        e.set_colour_model(&model).unwrap();
        e.set_contrast_table(&table).unwrap();
        let mut out = Vec::new();
        e.evaluate(&frame, &params, &ps, &mut out).unwrap();
        assert!(!e.fell_back() && e.take_notice().is_none());
        assert_eq!(out, vec![TermLogs::default(); 2]);

        // The failing call is repeated on the CPU, with the model and table given before.
        e.evaluate(&frame, &params, &ps, &mut out).unwrap();
        assert!(e.fell_back());
        let notice = e.take_notice().expect("a notice");
        assert!(
            notice.contains("GPU device lost") && notice.contains("CPU"),
            "{notice}"
        );
        assert!(e.take_notice().is_none(), "one notice only");
        assert!(e.name().starts_with("cpu"), "{}", e.name());
        let mut cpu = CpuEngine::new();
        cpu.set_colour_model(&model).unwrap();
        cpu.set_contrast_table(&table).unwrap();
        let mut want = Vec::new();
        cpu.evaluate(&frame, &params, &ps, &mut want).unwrap();
        assert!(want[0].contrast > 0.0, "{want:?}");
        assert_eq!(out, want);
        e.evaluate(&frame, &params, &ps, &mut out).unwrap();
        assert_eq!(out, want);
        assert!(e.take_notice().is_none());
    }

    /// A GPU engine whose device is lost after its first colour model: it reports the loss
    /// before looking at what it is given.
    struct LostAfterModel {
        models: usize,
    }

    impl LikelihoodEngine for LostAfterModel {
        fn name(&self) -> String {
            "lost (Vulkan)".into()
        }
        fn set_colour_model(&mut self, _: &ColourHistogram) -> Result<(), LikelihoodError> {
            self.models += 1;
            if self.models > 1 {
                return Err(LikelihoodError::DeviceLost("Destroyed: test".into()));
            }
            Ok(())
        }
        fn set_contrast_table(&mut self, _: &ContrastTable) -> Result<(), LikelihoodError> {
            Err(LikelihoodError::DeviceLost("Destroyed: test".into()))
        }
        fn evaluate(
            &mut self,
            _: &FrameInput<'_>,
            _: &LikelihoodParams,
            _: &[Particle],
            _: &mut Vec<TermLogs>,
        ) -> Result<(), LikelihoodError> {
            Err(LikelihoodError::DeviceLost("Destroyed: test".into()))
        }
    }

    /// A bad model given to a lost device is refused, as the CPU engine refuses it, and the
    /// earlier model stays: it was recorded unchecked, the fall-back then failed on it, and
    /// the engine stayed on the lost device, every later step failing on the bad model.
    #[test]
    fn a_bad_model_given_to_a_lost_device_is_refused_and_the_good_one_kept() {
        let img = image::RgbImage::from_pixel(32, 24, image::Rgb([200, 40, 40]));
        let good = red_model();
        let mut bad = good.clone();
        bad.0[0] = -1.0;
        let mut e = FallbackEngine::new(Box::new(LostAfterModel { models: 0 }));
        e.set_colour_model(&good).unwrap();
        assert!(e.set_colour_model(&bad).is_err());
        assert!(e.fell_back(), "the loss was seen");
        let frame = red_frame(&img);
        let params = LikelihoodParams {
            terms: crate::likelihood::TERM_COLOUR,
            ..Default::default()
        };
        let mut out = Vec::new();
        e.evaluate(&frame, &params, &[frame.prev], &mut out)
            .unwrap();
        let mut cpu = CpuEngine::new();
        cpu.set_colour_model(&good).unwrap();
        let mut want = Vec::new();
        cpu.evaluate(&frame, &params, &[frame.prev], &mut want)
            .unwrap();
        assert_eq!(out, want);
    }

    /// Where the work runs follows the engine in use: the device's elsewhere, the CPU
    /// engine's on the caller's pool once the device is lost.
    #[test]
    fn the_work_runs_on_the_calling_pool_once_fallen_back_to_the_cpu() {
        let mut e = FallbackEngine::new(Box::new(LostAfterModel { models: 0 }));
        assert!(e.set_colour_model(&red_model()).is_ok());
        assert!(!e.fell_back() && !e.runs_on_calling_pool());
        // The device is lost on the second model.
        assert!(e.set_colour_model(&red_model()).is_ok());
        assert!(e.fell_back());
        assert!(e.runs_on_calling_pool());
    }

    #[test]
    fn other_errors_pass_through() {
        let mut e = FallbackEngine::new(Box::new(CpuEngine::new()));
        let img = image::RgbImage::new(8, 8);
        let frame = FrameInput {
            image: &img,
            features: &[],
            depths: None,
            prev: Particle::default(),
            theta0: 0.0,
        };
        let mut out = Vec::new();
        let r = e.evaluate(&frame, &LikelihoodParams::default(), &[], &mut out);
        assert!(matches!(r, Err(LikelihoodError::NoModel)), "{r:?}");
        assert!(!e.fell_back());
    }
}
