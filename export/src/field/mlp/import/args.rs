//! A nerf-pytorch run's settings: `args.txt` (every argument, `key = value`, written by
//! `run_nerf.py` at the start of training) or the `config.txt` it was started with (a
//! configargparse file; settings it leaves out take nerf-pytorch's defaults).

use super::ImportError;
use std::path::Path;

/// The settings that decide what a nerf-pytorch checkpoint computes, named as in
/// `run_nerf.py`'s `config_parser`, with its defaults.
#[derive(Debug, Clone, PartialEq)]
pub struct NerfPytorchArgs {
    /// Layers of the coarse network's trunk (D).
    pub netdepth: usize,
    /// Width of the coarse network (W).
    pub netwidth: usize,
    /// Layers of the fine network's trunk.
    pub netdepth_fine: usize,
    /// Width of the fine network.
    pub netwidth_fine: usize,
    /// Frequencies of the position encoding (L = 10 → 63 inputs).
    pub multires: usize,
    /// Frequencies of the direction encoding (L = 4 → 27 inputs).
    pub multires_views: usize,
    /// 0: positional encoding; −1: none.
    pub i_embed: i64,
    /// Colour depends on the view direction.
    pub use_viewdirs: bool,
    /// Coarse samples per ray.
    pub n_samples: usize,
    /// Fine samples per ray (0: no fine network).
    pub n_importance: usize,
    /// Composite over white.
    pub white_bkgd: bool,
    /// Sample linearly in disparity.
    pub lindisp: bool,
    /// Training-time jitter of the coarse samples (off at test time, as here).
    pub perturb: f64,
    /// Training-time noise on the density (off at test time, as here).
    pub raw_noise_std: f64,
    /// `blender`, `llff`, `deepvoxels` or `LINEMOD`.
    pub dataset_type: String,
    /// Blender images loaded at half their size.
    pub half_res: bool,
    /// LLFF without normalised device coordinates.
    pub no_ndc: bool,
    /// LLFF images downsampled by this factor (`images_<factor>`).
    pub factor: usize,
    /// LLFF test views: every `llffhold`-th image.
    pub llffhold: usize,
    /// LLFF 360° captures re-posed on a sphere (not supported).
    pub spherify: bool,
    /// Where the run's data was (as nerf-pytorch saw it).
    pub datadir: Option<String>,
}

impl Default for NerfPytorchArgs {
    /// nerf-pytorch's defaults (`config_parser`).
    fn default() -> Self {
        NerfPytorchArgs {
            netdepth: 8,
            netwidth: 256,
            netdepth_fine: 8,
            netwidth_fine: 256,
            multires: 10,
            multires_views: 4,
            i_embed: 0,
            use_viewdirs: false,
            n_samples: 64,
            n_importance: 0,
            white_bkgd: false,
            lindisp: false,
            perturb: 1.0,
            raw_noise_std: 0.0,
            dataset_type: "llff".into(),
            half_res: false,
            no_ndc: false,
            factor: 8,
            llffhold: 8,
            spherify: false,
            datadir: None,
        }
    }
}

/// Settings the importer reads; everything else in the file (expname, lrate, …) is ignored.
const KNOWN: [&str; 21] = [
    "netdepth", "netwidth", "netdepth_fine", "netwidth_fine", "multires", "multires_views", "i_embed", "use_viewdirs",
    "N_samples", "N_importance", "white_bkgd", "lindisp", "perturb", "raw_noise_std", "dataset_type", "half_res", "no_ndc",
    "factor", "llffhold", "spherify", "datadir",
];

impl NerfPytorchArgs {
    /// Read `args.txt` or `config.txt`.
    pub fn read(path: &Path) -> Result<Self, ImportError> {
        let text = std::fs::read_to_string(path).map_err(|e| ImportError::args(path, e.to_string()))?;
        Self::parse(&text).map_err(|m| ImportError::args(path, m))
    }

    /// Parse the text of `args.txt` / `config.txt`: one `key = value` (or `key: value`) per
    /// line, `#` comments; booleans as Python writes them (`True`) or configargparse reads
    /// them (`true`, `yes`, `1`).
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut args = NerfPytorchArgs::default();
        let mut found = 0;
        for (n, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() || line.starts_with('[') {
                continue;
            }
            let Some(split) = line.find(['=', ':']) else { continue };
            let key = line[..split].trim().trim_start_matches("--");
            let value = line[split + 1..].trim().trim_matches(['"', '\'']);
            if !KNOWN.contains(&key) {
                continue;
            }
            found += 1;
            args.set(key, value).map_err(|why| format!("line {}: {key} = {value}: {why}", n + 1))?;
        }
        if found == 0 {
            return Err(format!("none of nerf-pytorch's settings ({}, …) found: not an args.txt or config.txt of a nerf-pytorch run", KNOWN[..4].join(", ")));
        }
        Ok(args)
    }

    fn set(&mut self, key: &str, value: &str) -> Result<(), String> {
        let int = |v: &str| v.parse::<usize>().map_err(|_| "not a non-negative integer".to_string());
        let float = |v: &str| v.parse::<f64>().map_err(|_| "not a number".to_string());
        let flag = |v: &str| match v.to_ascii_lowercase().as_str() {
            "true" | "yes" | "on" | "1" => Ok(true),
            "false" | "no" | "off" | "0" => Ok(false),
            _ => Err("not a boolean (True/False)".to_string()),
        };
        match key {
            "netdepth" => self.netdepth = int(value)?,
            "netwidth" => self.netwidth = int(value)?,
            "netdepth_fine" => self.netdepth_fine = int(value)?,
            "netwidth_fine" => self.netwidth_fine = int(value)?,
            "multires" => self.multires = int(value)?,
            "multires_views" => self.multires_views = int(value)?,
            "i_embed" => self.i_embed = value.parse().map_err(|_| "not an integer".to_string())?,
            "use_viewdirs" => self.use_viewdirs = flag(value)?,
            "N_samples" => self.n_samples = int(value)?,
            "N_importance" => self.n_importance = int(value)?,
            "white_bkgd" => self.white_bkgd = flag(value)?,
            "lindisp" => self.lindisp = flag(value)?,
            "perturb" => self.perturb = float(value)?,
            "raw_noise_std" => self.raw_noise_std = float(value)?,
            "dataset_type" => self.dataset_type = value.to_string(),
            "half_res" => self.half_res = flag(value)?,
            "no_ndc" => self.no_ndc = flag(value)?,
            "factor" => self.factor = int(value)?,
            "llffhold" => self.llffhold = int(value)?,
            "spherify" => self.spherify = flag(value)?,
            "datadir" => self.datadir = Some(value.to_string()),
            _ => unreachable!("KNOWN lists the keys handled here"),
        }
        Ok(())
    }

    /// Refuse what a scene bundle cannot express, naming the setting.
    pub fn check_supported(&self) -> Result<(), (&'static str, String, String)> {
        let unsupported = |setting: &'static str, value: String, why: &str| Err((setting, value, why.to_string()));
        if self.i_embed != 0 {
            return unsupported("i_embed", self.i_embed.to_string(), "only the positional encoding (i_embed = 0) is supported; the graphs always encode their inputs");
        }
        match self.dataset_type.as_str() {
            "blender" => {}
            "llff" if self.spherify => {
                return unsupported("spherify", "True".into(), "LLFF runs re-posed on a sphere (spherify) are not supported; forward-facing ones (NDC rays or no_ndc) are");
            }
            "llff" if self.llffhold == 0 => {
                return unsupported("llffhold", "0".into(), "the test views must be every llffhold-th image (llffhold > 0)");
            }
            "llff" => {}
            other => return unsupported("dataset_type", other.into(), "only Blender and LLFF scenes (dataset_type = blender or llff) are supported"),
        }
        if self.n_samples < 2 || (self.n_importance > 0 && self.n_samples < 3) {
            return unsupported("N_samples", self.n_samples.to_string(), "need at least 2 coarse samples (3 with N_importance > 0)");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_args_txt_as_run_nerf_writes_it() {
        let text = "N_importance = 64\nN_rand = 512\nN_samples = 32\nbasedir = ./logs\nconfig = configs/lego.txt\n\
                    dataset_type = blender\nft_path = None\nhalf_res = True\ni_embed = 0\nlindisp = False\nmultires = 8\n\
                    multires_views = 3\nnetdepth = 6\nnetdepth_fine = 4\nnetwidth = 64\nnetwidth_fine = 32\nno_ndc = False\n\
                    perturb = 1.0\nraw_noise_std = 0.0\nuse_viewdirs = True\nwhite_bkgd = True\n";
        let a = NerfPytorchArgs::parse(text).unwrap();
        assert_eq!((a.netdepth, a.netwidth, a.netdepth_fine, a.netwidth_fine), (6, 64, 4, 32));
        assert_eq!((a.multires, a.multires_views, a.n_samples, a.n_importance), (8, 3, 32, 64));
        assert!(a.use_viewdirs && a.white_bkgd && a.half_res && !a.lindisp);
        assert_eq!(a.dataset_type, "blender");
        assert!(a.check_supported().is_ok());
    }

    #[test]
    fn config_txt_falls_back_to_nerf_pytorch_defaults() {
        let a = NerfPytorchArgs::parse("# lego\nexpname = x\ndataset_type = blender\nuse_viewdirs: true\n").unwrap();
        assert_eq!((a.netdepth, a.netwidth, a.n_samples, a.n_importance, a.multires), (8, 256, 64, 0, 10));
        assert!(a.use_viewdirs && !a.white_bkgd);
        // nerf-pytorch's default dataset is LLFF with NDC rays, images_8, every 8th view held out.
        let d = NerfPytorchArgs::parse("netdepth = 8\n").unwrap();
        assert_eq!((d.dataset_type.as_str(), d.no_ndc, d.factor, d.llffhold, d.spherify), ("llff", false, 8, 8, false));
        assert!(d.check_supported().is_ok());
    }

    #[test]
    fn refuses_what_a_bundle_cannot_express() {
        let a = NerfPytorchArgs::parse("dataset_type = blender\ni_embed = -1\n").unwrap();
        assert_eq!(a.check_supported().unwrap_err().0, "i_embed");
        let sphere = NerfPytorchArgs::parse("dataset_type = llff\nspherify = True\n").unwrap();
        assert_eq!(sphere.check_supported().unwrap_err().0, "spherify");
        let no_test = NerfPytorchArgs::parse("dataset_type = llff\nllffhold = 0\n").unwrap();
        assert_eq!(no_test.check_supported().unwrap_err().0, "llffhold");
        let dv = NerfPytorchArgs::parse("dataset_type = deepvoxels\n").unwrap();
        assert_eq!(dv.check_supported().unwrap_err().1, "deepvoxels");
    }

    #[test]
    fn bad_files_say_which_line() {
        assert!(NerfPytorchArgs::parse("netdepth = eight\n").unwrap_err().contains("line 1: netdepth = eight"));
        assert!(NerfPytorchArgs::parse("use_viewdirs = maybe\n").unwrap_err().contains("boolean"));
        assert!(NerfPytorchArgs::parse("{\"lr\": 0.1}\n").unwrap_err().contains("not an args.txt"));
    }
}
