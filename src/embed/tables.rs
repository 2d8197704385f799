//! The transfer-function tables on the GPU: the 1D classification table of the frame's sampling
//! model and, when a frame asks for pre-integration, the 2D pre-integration table. Both are
//! rebuilt on the CPU when what they depend on changes and uploaded by the next record.

use crate::error::Result;
use crate::gpu::{Access, GpuContext, Image, ImageDesc, StagingUpload};
use crate::optics::preintegration::PreintegrationTable;
use crate::optics::{ClassificationTable, SamplingModel, TfPreset, TransferFunction, TF_SIZE};
use ash::vk;

/// Format of both tables.
const TABLE_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

/// One table image and its pending upload.
struct TableImage {
    image: Image,
    /// Bytes to upload with the next record.
    pending: Option<Vec<u8>>,
    /// Whether the image holds data (a later upload waits for earlier fragment reads).
    initialized: bool,
}

impl TableImage {
    fn new(image: Image) -> Self {
        Self {
            image,
            pending: None,
            initialized: false,
        }
    }

    /// Records the pending upload, if any, through `staging`; returns whether there was one.
    fn record(&mut self, cmd: vk::CommandBuffer, staging: &mut StagingUpload) -> Result<bool> {
        let Some(bytes) = self.pending.take() else {
            return Ok(false);
        };
        let previous = if self.initialized {
            Access::FragmentSampled
        } else {
            Access::Nothing
        };
        staging.record_whole_image(cmd, &self.image, &bytes, previous)?;
        self.initialized = true;
        Ok(true)
    }
}

/// The transfer function and its tables on the GPU.
pub(super) struct TransferTables {
    /// The classification table (TF_SIZE RGBA32F texels).
    classification: TableImage,
    /// The pre-integration table (TF_SIZE x TF_SIZE RGBA32F), created on first use.
    preintegration: Option<TableImage>,
    /// (model, step ratio bits) the pre-integration table (or its pending upload) was built for;
    /// `None` after a transfer-function change.
    preintegration_key: Option<(SamplingModel, u32)>,
    /// The transfer function, and the sampling model the classification table was built for.
    tf: TransferFunction,
    tf_model: Option<SamplingModel>,
    ctx: GpuContext,
}

impl TransferTables {
    /// Checks the table format and creates the classification table image (grey ramp until
    /// [`TransferTables::set`]).
    pub(super) fn new(ctx: &GpuContext) -> Result<Self> {
        let shared = &ctx.shared;
        shared.require_format(
            TABLE_FORMAT,
            vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR
                | vk::FormatFeatureFlags::TRANSFER_DST,
            "transfer function",
        )?;
        let image = Image::new(
            shared,
            "transfer function",
            ImageDesc::new_1d(
                TABLE_FORMAT,
                TF_SIZE as u32,
                vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
            ),
        )?;
        Ok(Self {
            classification: TableImage::new(image),
            preintegration: None,
            preintegration_key: None,
            tf: TransferFunction::preset(TfPreset::Grey),
            tf_model: None,
            ctx: ctx.clone(),
        })
    }

    /// Takes a new transfer function: both tables are rebuilt when next staged.
    pub(super) fn set(&mut self, tf: &TransferFunction) {
        self.tf = tf.clone();
        self.tf_model = None;
        self.preintegration_key = None;
    }

    /// Stages the classification table for `model` and, with `preintegration_ratio`, the 2D
    /// pre-integration table for steps of that many reference lengths, unless already there.
    pub(super) fn stage(
        &mut self,
        model: SamplingModel,
        preintegration_ratio: Option<f32>,
    ) -> Result<()> {
        if self.tf_model != Some(model) {
            let table = ClassificationTable::new(&self.tf, model);
            self.classification.pending = Some(bytemuck::cast_slice(table.entries()).to_vec());
            self.tf_model = Some(model);
        }
        let Some(ratio) = preintegration_ratio else {
            return Ok(());
        };
        let key = Some((model, ratio.to_bits()));
        if self.preintegration.is_some() && self.preintegration_key == key {
            return Ok(());
        }
        let table = PreintegrationTable::build(&ClassificationTable::new(&self.tf, model), ratio)?;
        let bytes = bytemuck::cast_slice(table.entries()).to_vec();
        if self.preintegration.is_none() {
            let image = Image::new(
                &self.ctx.shared,
                "pre-integration table",
                ImageDesc::new_2d(
                    TABLE_FORMAT,
                    TF_SIZE as u32,
                    TF_SIZE as u32,
                    vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST,
                ),
            )?;
            self.preintegration = Some(TableImage::new(image));
        }
        let pre = self.preintegration.as_mut().expect("created above");
        self.preintegration_key = key;
        pre.pending = Some(bytes);
        Ok(())
    }

    /// Records the staged uploads (pre-integration table first, then the classification table)
    /// through the frame slot's staging; returns whether anything was uploaded.
    pub(super) fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        tf_staging: &mut StagingUpload,
        preint_staging: &mut StagingUpload,
    ) -> Result<bool> {
        let mut uploaded = false;
        if let Some(pre) = &mut self.preintegration {
            uploaded |= pre.record(cmd, preint_staging)?;
        }
        uploaded |= self.classification.record(cmd, tf_staging)?;
        Ok(uploaded)
    }

    /// The transfer function the tables are built from.
    pub(super) fn transfer_function(&self) -> &TransferFunction {
        &self.tf
    }

    /// The classification table's view.
    pub(super) fn classification_view(&self) -> vk::ImageView {
        self.classification.image.view
    }

    /// The pre-integration table's view, once one was staged.
    pub(super) fn preintegration_view(&self) -> Option<vk::ImageView> {
        self.preintegration.as_ref().map(|p| p.image.view)
    }
}
