//! `logger`: taps every iceoryx2 service of a running stack into an MCAP file and the live
//! Foxglove view ([`motm_logger::service`]).

fn main() {
    motm_logger::service::main()
}
