//! Choosing an adapter and creating a device, by the rule the server's
//! solvers follow too ([`lightwire_adapter`]: a discrete GPU, then
//! integrated, virtual and software ones (lavapipe), native backends before
//! GL; `--adapter NAME` picks by a case-insensitive substring of the name).
//! The client may not depend on the server, so the rule lives in a crate of
//! its own that both link.

use lightwire_adapter::AdapterError;

use super::RenderError;

impl From<AdapterError> for RenderError {
    fn from(e: AdapterError) -> RenderError {
        match e {
            AdapterError::NoAdapter => RenderError::NoAdapter,
            AdapterError::NoMatchingAdapter { wanted, available } => {
                RenderError::NoMatchingAdapter { wanted, available }
            }
            AdapterError::RequestDevice { adapter, message } => {
                RenderError::RequestDevice { adapter, message }
            }
        }
    }
}

/// Picks an adapter (see the module doc) and opens a device with its
/// limits (large images and atlases need more than the defaults).
pub(super) async fn open(
    name: Option<&str>,
) -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), RenderError> {
    let adapter = lightwire_adapter::choose(name).await?;
    let (device, queue) =
        lightwire_adapter::request_device(&adapter, "lightwire-client view").await?;
    Ok((adapter, device, queue))
}
