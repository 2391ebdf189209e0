//! The base driver's hardware backends: the loop shared by the real bases ([`base`]), the
//! Omron LD-60 over ArNetworking and ARCL ([`arnl`]), AgileX bases over CAN ([`can`]), and
//! their settings ([`config`], `config/bases/*.toml`). The `sim` backend is `motm-driver`'s.
//! The process's flags and set-up over every backend: [`service`].

pub mod arnl;
pub mod base;
pub mod can;
pub mod config;
pub mod service;
