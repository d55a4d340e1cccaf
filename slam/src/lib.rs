//! # slam — object-recognition SLAM after Ramos, Nieto & Durrant-Whyte
//!
//! The paper's algorithm, usable on real robots: it depends on no simulator, renderer or
//! physics crate. Inputs are plain sensor data (SI units, REP-103 frames).
//!
//! - offline phase: [`features`] (Gabor bank, patches, PCA), [`gmm`] (VBEM Gaussian mixtures
//!   with birth-death model search), [`classifier`] (object vs background patches);
//! - online phase: [`clustering`] (laser), [`segmentation`] (laser-camera), [`object_model`],
//!   [`kl`] and [`association`] (KL, NN, JCBB), [`ekf`] (EKF-SLAM).

pub mod association;
pub mod calibration;
pub mod checkerboard;
pub mod classifier;
pub mod clustering;
pub mod column_context;
pub mod ekf;
pub mod evidence;
pub mod features;
pub mod gmm;
pub mod kl;
pub mod messages;
pub mod object_model;
pub mod pipeline;
pub mod segmentation;
pub mod settings;
