//! What every renderer asks of a field: rgb and σ at points seen from unit view directions.

/// Which network a batch of points is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The coarse network, on the stratified samples.
    Coarse,
    /// The fine network, on coarse ∪ importance samples.
    Fine,
}

/// A network's answer for a batch of points.
///
/// # Shapes
/// `rgb`: `[n]` of 3 (in [0, 1]); `sigma`: `[n]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FieldOutput {
    /// Colour per point.
    pub rgb: Vec<[f32; 3]>,
    /// Density σ per point. Exported graphs apply the ReLU, the burn networks leave it to
    /// compositing; either way a negative value counts as 0.
    pub sigma: Vec<f32>,
}

/// Something that evaluates the coarse and fine networks on points with unit view directions.
pub trait Field {
    /// The evaluator's error.
    type Error;
    /// Evaluate `stage`'s network on `points` `[n]` with `viewdirs` `[n]` (unit vectors).
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error>;
}

/// A borrowed field is a field, so renderers can hold `&mut F`.
impl<F: Field + ?Sized> Field for &mut F {
    type Error = F::Error;
    fn evaluate(&mut self, stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput, Self::Error> {
        (**self).evaluate(stage, points, viewdirs)
    }
}
