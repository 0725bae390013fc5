//! libFuzzer target: the las reader (through the content detection of `read_cloud`) must return,
//! never panic, on any bytes.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = nkrr::io::las::read_las(data);
    let _ = nkrr::io::read_cloud(data, None);
});
