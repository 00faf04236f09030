//! Compiles the protobuf contract without a system `protoc`: `protox` (pure Rust) parses the
//! .proto files into a FileDescriptorSet, prost-build generates the Rust types from it, and the
//! serialized set is kept for the MCAP schema records (standard tools decode messages with it).

use std::path::PathBuf;

use prost::Message;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto = "proto/chaoscope/v1/chaoscope.proto";
    println!("cargo:rerun-if-changed={proto}");
    let fds = protox::compile([proto], ["proto"])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("chaoscope_v1.fds.bin"), fds.encode_to_vec())?;
    prost_build::Config::new().compile_fds(fds)?;
    Ok(())
}
