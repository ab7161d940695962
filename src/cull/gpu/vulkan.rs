//! The Vulkan device behind `gpu`: one per process, driven from the
//! device thread only (Tai & Hsu's "hardware-accelerated occlusion query",
//! here on whatever Vulkan driver the machine has; lavapipe, Mesa's driver
//! on the CPU, in CI).
//!
//! What it does for the method: uploads a scene's triangles once
//! ([`Vulkan::upload`]), and runs views' traversals ([`QuerySource`]) in
//! lock-step ([`Vulkan::run`]): each step is one submission in which every
//! active view draws the depth of the objects it found visible since its
//! last step, then its next batch of box queries, each its own precise
//! occlusion query (`VK_QUERY_CONTROL_PRECISE_BIT`: exact sample counts).
//! Views that arrived together share the submissions, so the wait for the
//! device is paid once per step, not once per view.
//!
//! Depth is reversed (1 at the near plane, 0 at the far plane, `f32`), so
//! precision is even in relative depth at every distance. Every vertex is
//! moved to the eye before the rotation, the eye given as two `f32`s, so a
//! vertex near the eye keeps its precision however far both are from the
//! scene's origin (and the scene's origin is near its centre, so a scene
//! placed at 1e7 keeps it too). Pixels are sampled at their centres with one
//! sample, as ground truth does.
//!
//! The loader is opened at run time (ash's `loaded` feature): a machine
//! without Vulkan runs pvsd with `gpu` unsupported, saying why.

use std::io::Cursor;
use std::ops::Range;
use std::sync::Mutex;

use ash::vk;
use glam::{DVec3, Mat4, Vec3};

use crate::scene::Scene;

/// Views whose traversals run at once, each in its own depth image.
pub const SLOTS: usize = 16;

/// Queries one step may send for one view (the largest `batch`).
pub const MAX_QUERIES: u32 = 1024;

/// The importance mask of a view (§3.4), written into the stencil buffer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mask {
    /// 1 or 2: the paper's two mask types (see `shaders/mask.frag`).
    pub kind: u8,
    /// Share of the masked frame's pixels that are masked off.
    pub fill: f32,
}

/// How one view is drawn.
#[derive(Clone, Copy, Debug)]
pub struct Setup {
    /// Clip space from eye-relative, axis-aligned-to-the-scene coordinates.
    pub clip_from_view: Mat4,
    /// The eye, scene-local: scene vertices are moved by it on the device.
    pub eye: DVec3,
    /// Width and height in pixels.
    pub extent: [u32; 2],
    /// The importance mask, if any.
    pub mask: Option<Mask>,
}

/// A view's traversal as the device sees it: a setup, then passes until
/// it has no more.
pub trait QuerySource {
    /// How the view is drawn.
    fn setup(&self) -> Setup;
    /// Prepares the next pass into `draws` (scene triangle ranges to draw
    /// into depth first) and `boxes` (eye-relative boxes to query after,
    /// at most [`MAX_QUERIES`]); false when the traversal is done.
    fn next_pass(&mut self, draws: &mut Vec<Range<u32>>, boxes: &mut Vec<[Vec3; 2]>) -> bool;
    /// The sample count of each box of the last pass, in order.
    fn answer(&mut self, counts: &[u64]);
}

/// A scene's triangles on the device, uploaded once, with the neighbours
/// of their edges (the depth pass erodes only outlines, `shaders/scene.vert`).
pub struct SceneGeometry {
    buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    apices: vk::Buffer,
    apices_memory: vk::DeviceMemory,
    pool: vk::DescriptorPool,
    set: vk::DescriptorSet,
}

/// An edge without a neighbour in [`Vulkan::upload`]'s `apices`.
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// An edge whose neighbour lies in the same plane: the surface continues
/// across it from every view.
pub const FLAT: u32 = u32::MAX - 1;

/// What [`Vulkan::run`] spent, for the README's "where the time goes".
#[derive(Clone, Copy, Debug, Default)]
pub struct StepTimes {
    /// Submissions made.
    pub steps: u64,
    /// Recording command buffers, seconds.
    pub record_s: f64,
    /// Waiting for the device (its rasterization and queries), seconds.
    pub device_s: f64,
    /// Reading query results back, seconds.
    pub readback_s: f64,
}

/// One depth (and stencil) image with its query pool.
struct Slot {
    extent: [u32; 2],
    image: vk::Image,
    memory: vk::DeviceMemory,
    view: vk::ImageView,
    framebuffer: vk::Framebuffer,
    queries: vk::QueryPool,
}

/// The command buffer and the slots: used by the device thread only; the
/// mutex makes that a rule the compiler checks.
struct Recorder {
    pool: vk::CommandPool,
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    slots: Vec<Slot>,
}

/// The process's Vulkan device and the pipelines `gpu` draws with.
pub struct Vulkan {
    _entry: ash::Entry,
    instance: ash::Instance,
    device: ash::Device,
    queue: vk::Queue,
    name: String,
    memory: vk::PhysicalDeviceMemoryProperties,
    max_extent: [u32; 2],
    heap_bytes: u64,
    depth_format: vk::Format,
    pass_clear: vk::RenderPass,
    pass_load: vk::RenderPass,
    /// The depth pass reads the scene's vertices and edge neighbours.
    set_layout: vk::DescriptorSetLayout,
    layout: vk::PipelineLayout,
    modules: Vec<vk::ShaderModule>,
    depth_pipeline: vk::Pipeline,
    query_pipeline: vk::Pipeline,
    masked_query_pipeline: vk::Pipeline,
    mask_pipeline: vk::Pipeline,
    recorder: Mutex<Recorder>,
}

/// Counter-clockwise in the world is clockwise on the screen: the
/// projection flips y (Vulkan's y points down the framebuffer).
const FRONT_FACE: vk::FrontFace = vk::FrontFace::CLOCKWISE;

/// Push constants: the same block in every shader.
#[repr(C)]
#[derive(Clone, Copy)]
struct Push {
    clip_from_view: [f32; 16],
    eye: [f32; 4],
    box_min: [f32; 4],
    box_max: [f32; 4],
    /// What `eye` lost to rounding.
    eye_low: [f32; 4],
}

impl Push {
    fn bytes(&self) -> &[u8] {
        // SAFETY: `Push` is `repr(C)` plain `f32`s with no padding.
        unsafe {
            std::slice::from_raw_parts(
                (self as *const Push).cast::<u8>(),
                std::mem::size_of::<Push>(),
            )
        }
    }
}

fn spirv(bytes: &[u8]) -> Vec<u32> {
    ash::util::read_spv(&mut Cursor::new(bytes)).expect("build.rs wrote whole SPIR-V words")
}

/// The bytes of a slice of plain numbers.
fn bytes_of<T: Copy>(data: &[T]) -> &[u8] {
    // SAFETY: `T` is a plain array of `f32` or `u32` here: no padding, no
    // pointers; the bytes live as long as the slice.
    unsafe { std::slice::from_raw_parts(data.as_ptr().cast::<u8>(), std::mem::size_of_val(data)) }
}

fn vk_error(what: &str) -> impl Fn(vk::Result) -> String + '_ {
    move |e| format!("{what}: {e}")
}

impl Vulkan {
    /// Opens the machine's first Vulkan device that has a graphics queue
    /// and precise occlusion queries, or says why there is none.
    pub fn open() -> Result<Vulkan, String> {
        // SAFETY: loading the system's Vulkan loader; its functions are
        // called only through ash's checked wrappers below.
        let entry = unsafe { ash::Entry::load() }
            .map_err(|e| format!("no Vulkan loader on this machine ({e}); install mesa-vulkan-drivers for lavapipe"))?;
        let app = vk::ApplicationInfo::default()
            .application_name(c"pvsd")
            .api_version(vk::API_VERSION_1_1);
        let info = vk::InstanceCreateInfo::default().application_info(&app);
        // SAFETY: a valid create info with no extensions or layers.
        let instance = unsafe { entry.create_instance(&info, None) }
            .map_err(vk_error("no Vulkan driver could create an instance"))?;
        match Self::with_instance(entry, instance.clone()) {
            Ok(v) => Ok(v),
            Err(e) => {
                // SAFETY: nothing else was made from the instance.
                unsafe { instance.destroy_instance(None) };
                Err(e)
            }
        }
    }

    fn with_instance(entry: ash::Entry, instance: ash::Instance) -> Result<Vulkan, String> {
        // SAFETY: enumerating and querying a live instance.
        let physicals = unsafe { instance.enumerate_physical_devices() }
            .map_err(vk_error("listing Vulkan devices"))?;
        if physicals.is_empty() {
            return Err(
                "no Vulkan device (no driver found; install mesa-vulkan-drivers for lavapipe)"
                    .into(),
            );
        }
        let mut reasons = Vec::new();
        for physical in physicals {
            // SAFETY: querying a device the instance listed.
            let (props, features, families) = unsafe {
                (
                    instance.get_physical_device_properties(physical),
                    instance.get_physical_device_features(physical),
                    instance.get_physical_device_queue_family_properties(physical),
                )
            };
            let name = props
                .device_name_as_c_str()
                .unwrap_or(c"unnamed")
                .to_string_lossy()
                .into_owned();
            if features.occlusion_query_precise == vk::FALSE {
                reasons.push(format!("{name} has no precise occlusion queries"));
                continue;
            }
            let Some(family) = families
                .iter()
                .position(|f| f.queue_flags.contains(vk::QueueFlags::GRAPHICS))
            else {
                reasons.push(format!("{name} has no graphics queue"));
                continue;
            };
            return Self::with_device(entry, instance, physical, family as u32, name, &props);
        }
        Err(format!("no usable Vulkan device: {}", reasons.join("; ")))
    }

    fn with_device(
        entry: ash::Entry,
        instance: ash::Instance,
        physical: vk::PhysicalDevice,
        family: u32,
        name: String,
        props: &vk::PhysicalDeviceProperties,
    ) -> Result<Vulkan, String> {
        let priorities = [1.0];
        let queues = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(family)
            .queue_priorities(&priorities)];
        let features = vk::PhysicalDeviceFeatures::default().occlusion_query_precise(true);
        let info = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_features(&features);
        // SAFETY: the family and the feature were checked above.
        let device = unsafe { instance.create_device(physical, &info, None) }
            .map_err(vk_error("creating the Vulkan device"))?;
        // SAFETY: queue 0 of a family the device was created with.
        let queue = unsafe { device.get_device_queue(family, 0) };
        // SAFETY: querying a live physical device.
        let memory = unsafe { instance.get_physical_device_memory_properties(physical) };
        let heap_bytes = memory.memory_heaps[..memory.memory_heap_count as usize]
            .iter()
            .filter(|h| h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL))
            .map(|h| h.size)
            .max()
            .unwrap_or(0);
        let depth_format = [vk::Format::D32_SFLOAT_S8_UINT, vk::Format::D24_UNORM_S8_UINT]
            .into_iter()
            .find(|&f| {
                // SAFETY: querying a live physical device.
                let p = unsafe { instance.get_physical_device_format_properties(physical, f) };
                p.optimal_tiling_features
                    .contains(vk::FormatFeatureFlags::DEPTH_STENCIL_ATTACHMENT)
            })
            .ok_or_else(|| format!("{name} has no depth-stencil format"))?;
        if depth_format != vk::Format::D32_SFLOAT_S8_UINT {
            // A 24-bit depth buffer would round occluders in front of what
            // they do not hide: not conservative.
            // SAFETY: nothing was made from the device yet.
            unsafe { device.destroy_device(None) };
            return Err(format!("{name} has no 32-bit float depth-stencil format"));
        }
        let mut vulkan = Vulkan {
            _entry: entry,
            instance,
            device,
            queue,
            name,
            memory,
            max_extent: [
                props.limits.max_framebuffer_width,
                props.limits.max_framebuffer_height,
            ],
            heap_bytes,
            depth_format,
            pass_clear: vk::RenderPass::null(),
            pass_load: vk::RenderPass::null(),
            set_layout: vk::DescriptorSetLayout::null(),
            layout: vk::PipelineLayout::null(),
            modules: Vec::new(),
            depth_pipeline: vk::Pipeline::null(),
            query_pipeline: vk::Pipeline::null(),
            masked_query_pipeline: vk::Pipeline::null(),
            mask_pipeline: vk::Pipeline::null(),
            recorder: Mutex::new(Recorder {
                pool: vk::CommandPool::null(),
                cmd: vk::CommandBuffer::null(),
                fence: vk::Fence::null(),
                slots: Vec::new(),
            }),
        };
        // On failure, Drop destroys what was made (null handles are no-ops).
        vulkan.make_pipelines()?;
        vulkan.make_recorder(family)?;
        Ok(vulkan)
    }

    /// The device's name (`llvmpipe (LLVM 15.0.6, 256 bits)` for lavapipe).
    pub fn name(&self) -> &str {
        &self.name
    }

    fn make_pipelines(&mut self) -> Result<(), String> {
        let d = &self.device;
        let pass = |load: vk::AttachmentLoadOp, initial: vk::ImageLayout| {
            let attachment = [vk::AttachmentDescription::default()
                .format(self.depth_format)
                .samples(vk::SampleCountFlags::TYPE_1)
                .load_op(load)
                .store_op(vk::AttachmentStoreOp::STORE)
                .stencil_load_op(load)
                .stencil_store_op(vk::AttachmentStoreOp::STORE)
                .initial_layout(initial)
                .final_layout(vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL)];
            let depth = vk::AttachmentReference::default()
                .attachment(0)
                .layout(vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL);
            let subpass = [vk::SubpassDescription::default()
                .pipeline_bind_point(vk::PipelineBindPoint::GRAPHICS)
                .depth_stencil_attachment(&depth)];
            // Each step's render pass reads the depth the last one wrote.
            let dependency = [vk::SubpassDependency::default()
                .src_subpass(vk::SUBPASS_EXTERNAL)
                .dst_subpass(0)
                .src_stage_mask(vk::PipelineStageFlags::LATE_FRAGMENT_TESTS)
                .dst_stage_mask(vk::PipelineStageFlags::EARLY_FRAGMENT_TESTS)
                .src_access_mask(vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE)
                .dst_access_mask(
                    vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_READ
                        | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE,
                )];
            let info = vk::RenderPassCreateInfo::default()
                .attachments(&attachment)
                .subpasses(&subpass)
                .dependencies(&dependency);
            // SAFETY: a valid single-subpass render pass.
            unsafe { d.create_render_pass(&info, None) }.map_err(vk_error("a render pass"))
        };
        self.pass_clear = pass(vk::AttachmentLoadOp::CLEAR, vk::ImageLayout::UNDEFINED)?;
        self.pass_load = pass(
            vk::AttachmentLoadOp::LOAD,
            vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL,
        )?;
        let range = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::VERTEX | vk::ShaderStageFlags::FRAGMENT)
            .size(std::mem::size_of::<Push>() as u32)];
        let bindings = [0, 1].map(|b| {
            vk::DescriptorSetLayoutBinding::default()
                .binding(b)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .descriptor_count(1)
                .stage_flags(vk::ShaderStageFlags::VERTEX)
        });
        let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&bindings);
        // SAFETY: two storage buffers for the vertex stage.
        self.set_layout = unsafe { d.create_descriptor_set_layout(&info, None) }
            .map_err(vk_error("a descriptor set layout"))?;
        let set_layouts = [self.set_layout];
        let info = vk::PipelineLayoutCreateInfo::default()
            .set_layouts(&set_layouts)
            .push_constant_ranges(&range);
        // SAFETY: a layout with one push constant range.
        self.layout = unsafe { d.create_pipeline_layout(&info, None) }
            .map_err(vk_error("a pipeline layout"))?;

        let mut module = |bytes: &[u8]| -> Result<vk::ShaderModule, String> {
            let code = spirv(bytes);
            let info = vk::ShaderModuleCreateInfo::default().code(&code);
            // SAFETY: SPIR-V that naga validated at build time.
            let m = unsafe { d.create_shader_module(&info, None) }
                .map_err(vk_error("a shader module"))?;
            self.modules.push(m);
            Ok(m)
        };
        let scene_vert = module(include_bytes!(concat!(env!("OUT_DIR"), "/scene.vert.spv")))?;
        let box_vert = module(include_bytes!(concat!(env!("OUT_DIR"), "/box.vert.spv")))?;
        let screen_vert = module(include_bytes!(concat!(env!("OUT_DIR"), "/screen.vert.spv")))?;
        let nothing = module(include_bytes!(concat!(env!("OUT_DIR"), "/nothing.frag.spv")))?;
        let mask_frag = module(include_bytes!(concat!(env!("OUT_DIR"), "/mask.frag.spv")))?;
        let erode = module(include_bytes!(concat!(env!("OUT_DIR"), "/erode.frag.spv")))?;

        let stencil_equal_zero = vk::StencilOpState::default()
            .compare_op(vk::CompareOp::EQUAL)
            .fail_op(vk::StencilOp::KEEP)
            .pass_op(vk::StencilOp::KEEP)
            .depth_fail_op(vk::StencilOp::KEEP)
            .compare_mask(0xff)
            .reference(0);
        let stencil_write_one = vk::StencilOpState::default()
            .compare_op(vk::CompareOp::ALWAYS)
            .pass_op(vk::StencilOp::REPLACE)
            .fail_op(vk::StencilOp::KEEP)
            .depth_fail_op(vk::StencilOp::REPLACE)
            .compare_mask(0xff)
            .write_mask(0xff)
            .reference(1);
        struct Kind {
            vert: vk::ShaderModule,
            frag: vk::ShaderModule,
            cull: vk::CullModeFlags,
            vertex_input: bool,
            depth_test: bool,
            depth_write: bool,
            stencil: Option<vk::StencilOpState>,
        }
        // Front faces only: each pixel of a box counts once (a queried box
        // never reaches the near plane).
        let query = |stencil| Kind {
            vert: box_vert,
            frag: nothing,
            cull: vk::CullModeFlags::BACK,
            vertex_input: false,
            depth_test: true,
            depth_write: false,
            stencil,
        };
        let kinds = [
            // Occluder depth: the scene's triangles.
            Kind {
                vert: scene_vert,
                frag: erode,
                // Walls seen from behind hide too.
                cull: vk::CullModeFlags::NONE,
                vertex_input: true,
                depth_test: true,
                depth_write: true,
                stencil: None,
            },
            // A query: a box, depth-tested, writing nothing.
            query(None),
            // A query counting only the important pixels.
            query(Some(stencil_equal_zero)),
            // The importance mask into the stencil.
            Kind {
                vert: screen_vert,
                frag: mask_frag,
                cull: vk::CullModeFlags::NONE,
                vertex_input: false,
                depth_test: false,
                depth_write: false,
                stencil: Some(stencil_write_one),
            },
        ];
        let mut pipelines = Vec::new();
        for k in &kinds {
            let stages = [
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::VERTEX)
                    .module(k.vert)
                    .name(c"main"),
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::FRAGMENT)
                    .module(k.frag)
                    .name(c"main"),
            ];
            let bindings = [vk::VertexInputBindingDescription::default()
                .binding(0)
                .stride(16)
                .input_rate(vk::VertexInputRate::VERTEX)];
            let attributes = [vk::VertexInputAttributeDescription::default()
                .location(0)
                .binding(0)
                .format(vk::Format::R32G32B32A32_SFLOAT)
                .offset(0)];
            let vertex_input = if k.vertex_input {
                vk::PipelineVertexInputStateCreateInfo::default()
                    .vertex_binding_descriptions(&bindings)
                    .vertex_attribute_descriptions(&attributes)
            } else {
                vk::PipelineVertexInputStateCreateInfo::default()
            };
            let assembly = vk::PipelineInputAssemblyStateCreateInfo::default()
                .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
            let viewport = vk::PipelineViewportStateCreateInfo::default()
                .viewport_count(1)
                .scissor_count(1);
            let raster = vk::PipelineRasterizationStateCreateInfo::default()
                .polygon_mode(vk::PolygonMode::FILL)
                .cull_mode(k.cull)
                .front_face(FRONT_FACE)
                .line_width(1.0);
            let multisample = vk::PipelineMultisampleStateCreateInfo::default()
                .rasterization_samples(vk::SampleCountFlags::TYPE_1);
            let mut depth = vk::PipelineDepthStencilStateCreateInfo::default()
                .depth_test_enable(k.depth_test)
                .depth_write_enable(k.depth_write)
                // Reversed depth: nearer is greater; a box face level with
                // an occluder still counts.
                .depth_compare_op(vk::CompareOp::GREATER_OR_EQUAL);
            if let Some(s) = k.stencil {
                depth = depth.stencil_test_enable(true).front(s).back(s);
            }
            let blend = vk::PipelineColorBlendStateCreateInfo::default();
            let dynamic_states = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
            let dynamic =
                vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic_states);
            let info = vk::GraphicsPipelineCreateInfo::default()
                .stages(&stages)
                .vertex_input_state(&vertex_input)
                .input_assembly_state(&assembly)
                .viewport_state(&viewport)
                .rasterization_state(&raster)
                .multisample_state(&multisample)
                .depth_stencil_state(&depth)
                .color_blend_state(&blend)
                .dynamic_state(&dynamic)
                .layout(self.layout)
                .render_pass(self.pass_clear);
            // SAFETY: every state the pipeline reads is set above.
            let made = unsafe {
                d.create_graphics_pipelines(vk::PipelineCache::null(), &[info], None)
            }
            .map_err(|(_, e)| format!("a graphics pipeline: {e}"))?;
            pipelines.push(made[0]);
        }
        [
            self.depth_pipeline,
            self.query_pipeline,
            self.masked_query_pipeline,
            self.mask_pipeline,
        ] = [pipelines[0], pipelines[1], pipelines[2], pipelines[3]];
        Ok(())
    }

    fn make_recorder(&mut self, family: u32) -> Result<(), String> {
        let d = &self.device;
        let r = self.recorder.get_mut().expect("not shared yet");
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        // SAFETY: a pool for a family the device has.
        r.pool = unsafe { d.create_command_pool(&info, None) }.map_err(vk_error("a command pool"))?;
        let info = vk::CommandBufferAllocateInfo::default()
            .command_pool(r.pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        // SAFETY: one primary buffer from the pool just made.
        r.cmd = unsafe { d.allocate_command_buffers(&info) }
            .map_err(vk_error("a command buffer"))?[0];
        // SAFETY: a plain fence.
        r.fence = unsafe { d.create_fence(&vk::FenceCreateInfo::default(), None) }
            .map_err(vk_error("a fence"))?;
        Ok(())
    }

    fn memory_type(&self, bits: u32, wanted: vk::MemoryPropertyFlags) -> Option<u32> {
        (0..self.memory.memory_type_count).find(|&i| {
            bits & (1 << i) != 0
                && self.memory.memory_types[i as usize]
                    .property_flags
                    .contains(wanted)
        })
    }

    /// Uploads every triangle of `scene` (scene-local `f32`, three vertices
    /// each, in the scene's order, so an object's triangle range is its
    /// vertex range ×3), then the `extra` triangles, with `apices`: per
    /// triangle (scene's, then extra) and corner, the vertex index of the
    /// neighbour across the opposite edge, or [`NO_NEIGHBOUR`]. Says why
    /// when the device cannot hold them.
    pub fn upload(
        &self,
        scene: &Scene,
        extra: &[[Vec3; 3]],
        apices: &[[u32; 3]],
    ) -> Result<SceneGeometry, String> {
        let count = scene.triangles().len() + extra.len();
        assert_eq!(apices.len(), count, "one set of neighbours a triangle");
        let vertices: Vec<[f32; 4]> = scene
            .triangles()
            .iter()
            .chain(extra)
            .flat_map(|t| t.map(|v| v.extend(1.0).to_array()))
            .collect();
        let bytes = std::mem::size_of_val(vertices.as_slice()) as u64
            + std::mem::size_of_val(apices) as u64;
        // Leave room for the depth images and everything else.
        if bytes > self.heap_bytes / 4 {
            return Err(format!(
                "the scene's {} triangles ({} MB) do not fit the device's memory ({} MB)",
                count,
                bytes >> 20,
                self.heap_bytes >> 20
            ));
        }
        let usage = vk::BufferUsageFlags::VERTEX_BUFFER | vk::BufferUsageFlags::STORAGE_BUFFER;
        let (buffer, memory) = self.host_buffer(bytes_of(&vertices), usage)?;
        let (apices_buffer, apices_memory) =
            match self.host_buffer(bytes_of(apices), vk::BufferUsageFlags::STORAGE_BUFFER) {
                Ok(b) => b,
                Err(e) => {
                    self.free_buffer(buffer, memory);
                    return Err(e);
                }
            };
        let (pool, set) = match self.descriptor_set(buffer, apices_buffer) {
            Ok(s) => s,
            Err(e) => {
                self.free_buffer(buffer, memory);
                self.free_buffer(apices_buffer, apices_memory);
                return Err(e);
            }
        };
        Ok(SceneGeometry {
            buffer,
            memory,
            apices: apices_buffer,
            apices_memory,
            pool,
            set,
        })
    }

    /// A buffer in host-visible memory holding `data`.
    fn host_buffer(
        &self,
        data: &[u8],
        usage: vk::BufferUsageFlags,
    ) -> Result<(vk::Buffer, vk::DeviceMemory), String> {
        let d = &self.device;
        let size = (data.len() as u64).max(16);
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: a plain buffer.
        let buffer = unsafe { d.create_buffer(&info, None) }.map_err(vk_error("a buffer"))?;
        // SAFETY: the buffer just made.
        let needs = unsafe { d.get_buffer_memory_requirements(buffer) };
        let host = vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT;
        let Some(kind) = self.memory_type(needs.memory_type_bits, host) else {
            // SAFETY: the buffer is unused.
            unsafe { d.destroy_buffer(buffer, None) };
            return Err("the device has no host-visible memory for the scene".into());
        };
        let info = vk::MemoryAllocateInfo::default()
            .allocation_size(needs.size)
            .memory_type_index(kind);
        // SAFETY: an allocation of a type the buffer accepts; mapped whole,
        // filled with `data`, unmapped, then bound.
        unsafe {
            let memory = match d.allocate_memory(&info, None) {
                Ok(m) => m,
                Err(e) => {
                    d.destroy_buffer(buffer, None);
                    return Err(format!(
                        "the scene's {} MB do not fit the device's memory ({e})",
                        size >> 20
                    ));
                }
            };
            let filled = d
                .map_memory(memory, 0, needs.size, vk::MemoryMapFlags::empty())
                .map(|to| {
                    std::ptr::copy_nonoverlapping(data.as_ptr(), to.cast::<u8>(), data.len());
                    d.unmap_memory(memory);
                })
                .and_then(|()| d.bind_buffer_memory(buffer, memory, 0));
            if let Err(e) = filled {
                self.free_buffer(buffer, memory);
                return Err(format!("filling a buffer: {e}"));
            }
            Ok((buffer, memory))
        }
    }

    fn free_buffer(&self, buffer: vk::Buffer, memory: vk::DeviceMemory) {
        // SAFETY: called only for buffers no submission uses.
        unsafe {
            self.device.destroy_buffer(buffer, None);
            self.device.free_memory(memory, None);
        }
    }

    /// A pool with one set naming the two buffers the depth pass reads.
    fn descriptor_set(
        &self,
        positions: vk::Buffer,
        apices: vk::Buffer,
    ) -> Result<(vk::DescriptorPool, vk::DescriptorSet), String> {
        let d = &self.device;
        let sizes = [vk::DescriptorPoolSize {
            ty: vk::DescriptorType::STORAGE_BUFFER,
            descriptor_count: 2,
        }];
        let info = vk::DescriptorPoolCreateInfo::default()
            .max_sets(1)
            .pool_sizes(&sizes);
        // SAFETY: a pool for one set of two storage buffers.
        let pool = unsafe { d.create_descriptor_pool(&info, None) }
            .map_err(vk_error("a descriptor pool"))?;
        let layouts = [self.set_layout];
        let info = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(pool)
            .set_layouts(&layouts);
        // SAFETY: one set from the pool just made; written before use.
        let set = match unsafe { d.allocate_descriptor_sets(&info) } {
            Ok(sets) => sets[0],
            Err(e) => {
                // SAFETY: the pool holds nothing in use.
                unsafe { d.destroy_descriptor_pool(pool, None) };
                return Err(format!("a descriptor set: {e}"));
            }
        };
        let infos = [positions, apices].map(|b| {
            [vk::DescriptorBufferInfo::default()
                .buffer(b)
                .offset(0)
                .range(vk::WHOLE_SIZE)]
        });
        let writes = [0, 1].map(|i| {
            vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(i as u32)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .buffer_info(&infos[i])
        });
        // SAFETY: both buffers are live storage buffers.
        unsafe { d.update_descriptor_sets(&writes, &[]) };
        Ok((pool, set))
    }

    /// Frees a scene's triangles; the device thread must not be using them.
    pub fn release(&self, geometry: &SceneGeometry) {
        // SAFETY: every submission waits for its fence before `run`
        // returns, so nothing on the device reads the buffers now; the
        // pool frees its set.
        unsafe {
            let d = &self.device;
            d.destroy_descriptor_pool(geometry.pool, None);
            for (b, m) in [
                (geometry.buffer, geometry.memory),
                (geometry.apices, geometry.apices_memory),
            ] {
                d.destroy_buffer(b, None);
                d.free_memory(m, None);
            }
        }
    }

    /// Runs `sources` to the end on `geometry`, [`SLOTS`] at a time in
    /// lock-step, one submission per step.
    pub fn run(
        &self,
        geometry: &SceneGeometry,
        sources: &mut [&mut dyn QuerySource],
    ) -> Result<StepTimes, String> {
        let mut recorder = self.recorder.lock().unwrap_or_else(|p| p.into_inner());
        let r = &mut *recorder;
        let mut times = StepTimes::default();
        // (source, slot, first pass) of the views being run.
        let mut active: Vec<(usize, usize, bool)> = Vec::new();
        let mut next = 0;
        let mut draws = Vec::new();
        let mut boxes = Vec::new();
        // Per active view: how many queries its pass sent.
        let mut sent: Vec<u32> = Vec::new();
        loop {
            // Free slots take the next waiting views.
            while active.len() < SLOTS && next < sources.len() {
                let used: Vec<usize> = active.iter().map(|a| a.1).collect();
                let slot = (0..SLOTS).find(|s| !used.contains(s)).expect("a free slot");
                let extent = sources[next].setup().extent;
                self.ensure_slot(r, slot, extent)?;
                active.push((next, slot, true));
                next += 1;
            }
            if active.is_empty() {
                return Ok(times);
            }
            let started = std::time::Instant::now();
            let d = &self.device;
            // SAFETY: the command buffer is idle (the last step's fence was
            // waited for) and recorded from this thread only.
            unsafe {
                d.reset_command_buffer(r.cmd, vk::CommandBufferResetFlags::empty())
                    .map_err(vk_error("resetting the command buffer"))?;
                let begin = vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
                d.begin_command_buffer(r.cmd, &begin)
                    .map_err(vk_error("recording"))?;
            }
            sent.clear();
            let mut finished = Vec::new();
            let mut recorded_any = false;
            for (i, &(source, slot, first)) in active.iter().enumerate() {
                draws.clear();
                boxes.clear();
                let more = sources[source].next_pass(&mut draws, &mut boxes);
                if !more {
                    finished.push(i);
                    sent.push(0);
                    continue;
                }
                assert!(boxes.len() as u32 <= MAX_QUERIES, "a pass sends too many queries");
                let setup = sources[source].setup();
                self.record(r, geometry, &r.slots[slot], &setup, first, &draws, &boxes);
                sent.push(boxes.len() as u32);
                recorded_any = true;
            }
            for (i, a) in active.iter_mut().enumerate() {
                if !finished.contains(&i) {
                    a.2 = false;
                }
            }
            // SAFETY: ending the buffer begun above.
            unsafe { d.end_command_buffer(r.cmd) }.map_err(vk_error("recording"))?;
            let recorded = std::time::Instant::now();
            times.record_s += (recorded - started).as_secs_f64();
            if recorded_any {
                let cmds = [r.cmd];
                let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
                // SAFETY: a recorded buffer, an unsignalled fence; waited
                // for before anything it uses is touched again.
                unsafe {
                    d.queue_submit(self.queue, &submit, r.fence)
                        .map_err(vk_error("submitting"))?;
                    d.wait_for_fences(&[r.fence], true, u64::MAX)
                        .map_err(vk_error("waiting for the device"))?;
                    d.reset_fences(&[r.fence]).map_err(vk_error("a fence"))?;
                }
                times.steps += 1;
            }
            let waited = std::time::Instant::now();
            times.device_s += (waited - recorded).as_secs_f64();
            let mut counts = Vec::new();
            for (i, &(source, slot, _)) in active.iter().enumerate() {
                if finished.contains(&i) {
                    continue;
                }
                counts.clear();
                counts.resize(sent[i] as usize, 0u64);
                if sent[i] > 0 {
                    // SAFETY: the queries were reset, begun and ended in the
                    // submission the fence just signalled.
                    unsafe {
                        d.get_query_pool_results(
                            r.slots[slot].queries,
                            0,
                            &mut counts,
                            vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                        )
                    }
                    .map_err(vk_error("reading query results"))?;
                }
                sources[source].answer(&counts);
            }
            times.readback_s += waited.elapsed().as_secs_f64();
            for &i in finished.iter().rev() {
                active.remove(i);
            }
        }
    }

    /// Makes slot `index` at least `extent` large.
    fn ensure_slot(&self, r: &mut Recorder, index: usize, extent: [u32; 2]) -> Result<(), String> {
        if extent[0] > self.max_extent[0] || extent[1] > self.max_extent[1] {
            return Err(format!(
                "a {}×{} viewport is larger than the device draws ({}×{})",
                extent[0], extent[1], self.max_extent[0], self.max_extent[1]
            ));
        }
        if let Some(s) = r.slots.get(index)
            && s.extent[0] >= extent[0]
            && s.extent[1] >= extent[1]
        {
            return Ok(());
        }
        let grown = match r.slots.get(index) {
            Some(s) => [s.extent[0].max(extent[0]), s.extent[1].max(extent[1])],
            None => extent,
        };
        let slot = self.make_slot(grown)?;
        if index < r.slots.len() {
            let old = std::mem::replace(&mut r.slots[index], slot);
            self.destroy_slot(&old);
        } else {
            r.slots.push(slot);
        }
        Ok(())
    }

    fn make_slot(&self, extent: [u32; 2]) -> Result<Slot, String> {
        let d = &self.device;
        let info = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_2D)
            .format(self.depth_format)
            .extent(vk::Extent3D {
                width: extent[0],
                height: extent[1],
                depth: 1,
            })
            .mip_levels(1)
            .array_layers(1)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        // SAFETY: creating and binding a depth image within the device's limits.
        unsafe {
            let image = d.create_image(&info, None).map_err(vk_error("a depth image"))?;
            let needs = d.get_image_memory_requirements(image);
            let kind = self
                .memory_type(needs.memory_type_bits, vk::MemoryPropertyFlags::DEVICE_LOCAL)
                .or_else(|| {
                    self.memory_type(needs.memory_type_bits, vk::MemoryPropertyFlags::empty())
                })
                .ok_or("no memory type for a depth image")?;
            let alloc = vk::MemoryAllocateInfo::default()
                .allocation_size(needs.size)
                .memory_type_index(kind);
            let memory = d
                .allocate_memory(&alloc, None)
                .map_err(vk_error("depth image memory"))?;
            d.bind_image_memory(image, memory, 0)
                .map_err(vk_error("binding depth memory"))?;
            let view_info = vk::ImageViewCreateInfo::default()
                .image(image)
                .view_type(vk::ImageViewType::TYPE_2D)
                .format(self.depth_format)
                .subresource_range(vk::ImageSubresourceRange {
                    aspect_mask: vk::ImageAspectFlags::DEPTH | vk::ImageAspectFlags::STENCIL,
                    base_mip_level: 0,
                    level_count: 1,
                    base_array_layer: 0,
                    layer_count: 1,
                });
            let view = d
                .create_image_view(&view_info, None)
                .map_err(vk_error("a depth view"))?;
            let attachments = [view];
            let fb = vk::FramebufferCreateInfo::default()
                .render_pass(self.pass_clear)
                .attachments(&attachments)
                .width(extent[0])
                .height(extent[1])
                .layers(1);
            let framebuffer = d
                .create_framebuffer(&fb, None)
                .map_err(vk_error("a framebuffer"))?;
            let pool = vk::QueryPoolCreateInfo::default()
                .query_type(vk::QueryType::OCCLUSION)
                .query_count(MAX_QUERIES);
            let queries = d
                .create_query_pool(&pool, None)
                .map_err(vk_error("a query pool"))?;
            Ok(Slot {
                extent,
                image,
                memory,
                view,
                framebuffer,
                queries,
            })
        }
    }

    fn destroy_slot(&self, s: &Slot) {
        // SAFETY: slots are replaced or dropped only between steps, when
        // the device has finished with them.
        unsafe {
            let d = &self.device;
            d.destroy_query_pool(s.queries, None);
            d.destroy_framebuffer(s.framebuffer, None);
            d.destroy_image_view(s.view, None);
            d.destroy_image(s.image, None);
            d.free_memory(s.memory, None);
        }
    }

    /// Records one view's pass: its new occluders' depth, then its queries.
    #[allow(clippy::too_many_arguments)]
    fn record(
        &self,
        r: &Recorder,
        geometry: &SceneGeometry,
        slot: &Slot,
        setup: &Setup,
        first: bool,
        draws: &[Range<u32>],
        boxes: &[[Vec3; 2]],
    ) {
        let d = &self.device;
        let cmd = r.cmd;
        let [w, h] = setup.extent;
        let eye = setup.eye.as_vec3();
        let mut push = Push {
            clip_from_view: setup.clip_from_view.to_cols_array(),
            eye: eye.extend(0.0).to_array(),
            box_min: [0.0; 4],
            box_max: [0.0; 4],
            eye_low: (setup.eye - eye.as_dvec3()).as_vec3().extend(0.0).to_array(),
        };
        let stages = vk::ShaderStageFlags::VERTEX | vk::ShaderStageFlags::FRAGMENT;
        // SAFETY: recording into the buffer begun by `run`, with handles
        // owned by this device; the slot is at least `extent` large.
        unsafe {
            if !boxes.is_empty() {
                d.cmd_reset_query_pool(cmd, slot.queries, 0, boxes.len() as u32);
            }
            let clear = [vk::ClearValue {
                depth_stencil: vk::ClearDepthStencilValue {
                    depth: 0.0,
                    stencil: 0,
                },
            }];
            let area = vk::Rect2D {
                offset: vk::Offset2D { x: 0, y: 0 },
                extent: vk::Extent2D {
                    width: w,
                    height: h,
                },
            };
            let begin = vk::RenderPassBeginInfo::default()
                .render_pass(if first { self.pass_clear } else { self.pass_load })
                .framebuffer(slot.framebuffer)
                .render_area(area)
                .clear_values(&clear);
            d.cmd_begin_render_pass(cmd, &begin, vk::SubpassContents::INLINE);
            let viewport = vk::Viewport {
                x: 0.0,
                y: 0.0,
                width: w as f32,
                height: h as f32,
                min_depth: 0.0,
                max_depth: 1.0,
            };
            d.cmd_set_viewport(cmd, 0, &[viewport]);
            d.cmd_set_scissor(cmd, 0, &[area]);
            if first && let Some(mask) = setup.mask {
                d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.mask_pipeline);
                let mut p = push;
                p.box_min = [w as f32, h as f32, mask.kind as f32, mask.fill];
                d.cmd_push_constants(cmd, self.layout, stages, 0, p.bytes());
                d.cmd_draw(cmd, 3, 1, 0, 0);
            }
            if !draws.is_empty() {
                d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.depth_pipeline);
                d.cmd_bind_vertex_buffers(cmd, 0, &[geometry.buffer], &[0]);
                d.cmd_bind_descriptor_sets(
                    cmd,
                    vk::PipelineBindPoint::GRAPHICS,
                    self.layout,
                    0,
                    &[geometry.set],
                    &[],
                );
                d.cmd_push_constants(cmd, self.layout, stages, 0, push.bytes());
                for range in draws {
                    d.cmd_draw(cmd, (range.end - range.start) * 3, 1, range.start * 3, 0);
                }
            }
            if !boxes.is_empty() {
                let pipeline = if setup.mask.is_some() {
                    self.masked_query_pipeline
                } else {
                    self.query_pipeline
                };
                d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline);
                push.eye = [0.0; 4];
                push.eye_low = [0.0; 4];
                for (i, b) in boxes.iter().enumerate() {
                    push.box_min = b[0].extend(0.0).to_array();
                    push.box_max = b[1].extend(0.0).to_array();
                    d.cmd_push_constants(cmd, self.layout, stages, 0, push.bytes());
                    d.cmd_begin_query(cmd, slot.queries, i as u32, vk::QueryControlFlags::PRECISE);
                    d.cmd_draw(cmd, 36, 1, 0, 0);
                    d.cmd_end_query(cmd, slot.queries, i as u32);
                }
            }
            d.cmd_end_render_pass(cmd);
        }
    }
}

impl Drop for Vulkan {
    fn drop(&mut self) {
        let r = self.recorder.get_mut().unwrap_or_else(|p| p.into_inner());
        let slots = std::mem::take(&mut r.slots);
        let (pool, fence) = (r.pool, r.fence);
        for s in &slots {
            self.destroy_slot(s);
        }
        // SAFETY: the device is idle once `device_wait_idle` returns, and
        // every handle below was made by it (null handles are ignored).
        unsafe {
            let d = &self.device;
            let _ = d.device_wait_idle();
            d.destroy_fence(fence, None);
            d.destroy_command_pool(pool, None);
            for p in [
                self.depth_pipeline,
                self.query_pipeline,
                self.masked_query_pipeline,
                self.mask_pipeline,
            ] {
                d.destroy_pipeline(p, None);
            }
            for m in &self.modules {
                d.destroy_shader_module(*m, None);
            }
            d.destroy_pipeline_layout(self.layout, None);
            d.destroy_descriptor_set_layout(self.set_layout, None);
            d.destroy_render_pass(self.pass_clear, None);
            d.destroy_render_pass(self.pass_load, None);
            d.destroy_device(None);
            self.instance.destroy_instance(None);
        }
    }
}

impl std::fmt::Debug for Vulkan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Vulkan").field("device", &self.name).finish_non_exhaustive()
    }
}
