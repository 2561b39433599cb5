//! Large zeroed buffers for the score and cost volumes. Filling tens of MiB of fresh memory
//! costs a page fault per 4 KiB page; on Linux the buffer asks for transparent huge pages
//! (`madvise(MADV_HUGEPAGE)`, which the common "madvise" setting of
//! /sys/kernel/mm/transparent_hugepage/enabled grants on request), one fault per 2 MiB. It is
//! advice: where the kernel declines, the buffer is the same, only slower to fill.

/// `n` zeroed values, on huge pages where the kernel grants them.
pub fn zeroed<T: Copy + Default>(n: usize) -> Vec<T> {
    let mut v = vec![T::default(); n];
    advise_huge(&mut v);
    v
}

/// Smaller than this, a buffer is left as it is (huge pages pay from a few of them).
const WORTH: usize = 4 << 20;

#[cfg(target_os = "linux")]
fn advise_huge<T>(v: &mut [T]) {
    const PAGE: usize = 4096;
    let len = std::mem::size_of_val(v);
    if len < WORTH {
        return;
    }
    let start = v.as_mut_ptr() as usize;
    let aligned = start.next_multiple_of(PAGE);
    let span = (len - (aligned - start)) / PAGE * PAGE;
    // SAFETY: [aligned, aligned + span) lies within the buffer, which this function borrows
    // mutably; MADV_HUGEPAGE changes how the pages are backed, never their contents. Its
    // result is ignored on purpose: refused advice leaves an ordinary buffer.
    unsafe {
        libc::madvise(aligned as *mut libc::c_void, span, libc::MADV_HUGEPAGE);
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_huge<T>(_: &mut [T]) {}

#[cfg(test)]
mod tests {
    #[test]
    fn zeroed_is_zero_at_any_size() {
        for n in [0usize, 1, 4095, (8 << 20) + 3] {
            let v: Vec<u16> = crate::matching::plane_sweep::volume::zeroed(n);
            assert_eq!(v.len(), n);
            assert!(v.iter().all(|&x| x == 0));
        }
    }
}
