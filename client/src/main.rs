//! `lightwire-client`: watch, drive, view and load-test a Lightwire server.

fn main() -> std::process::ExitCode {
    eprintln!(
        "lightwire-client {} (protocol {}): no subcommands yet; the streaming server does not exist yet",
        env!("CARGO_PKG_VERSION"),
        lightwire_client::PROTOCOL_VERSION
    );
    std::process::ExitCode::FAILURE
}
