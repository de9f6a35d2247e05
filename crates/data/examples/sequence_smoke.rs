use data::sequence::{OpenOptions, Sequence};
fn main() {
    for dir in std::env::args().skip(1) {
        let t = std::time::Instant::now();
        match Sequence::open(&dir, &OpenOptions::default()) {
            Err(e) => println!("{dir}: ERROR {e}"),
            Ok(s) => {
                let i = s.info();
                println!(
                    "{dir}: {:?} {} frames size {:?} camera {:?} gt {} warnings {:?} open {:?}",
                    i.format,
                    i.frame_count,
                    i.size,
                    i.camera,
                    i.ground_truth.is_some(),
                    i.warnings,
                    t.elapsed()
                );
                let t = std::time::Instant::now();
                let n = s.len();
                let mut gt = 0;
                for f in s.into_reader(8) {
                    match f {
                        Ok(f) => {
                            if f.world_from_camera.is_some() {
                                gt += 1;
                            }
                        }
                        Err(e) => println!("  {e}"),
                    }
                }
                println!("  read {n} in {:?}, {gt} with gt", t.elapsed());
            }
        }
    }
}
