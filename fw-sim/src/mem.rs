//! The chip's SRAM and code flash as host buffers that unicorn maps by
//! pointer (`mem_map_ptr`), so that the DMA model reads and writes the same
//! bytes the CPU does. A buffer is allocated once and lives as long as the
//! process (the CPU keeps the pointer; a chip reset keeps the memories).

pub struct HostMem {
    base: u32,
    ptr: *mut u8,
    len: usize,
}

impl HostMem {
    pub fn new(base: u32, len: usize) -> Self {
        let ptr = Box::leak(vec![0u8; len].into_boxed_slice()).as_mut_ptr();
        Self { base, ptr, len }
    }
    pub fn ptr(&self) -> *mut u8 {
        self.ptr
    }
    pub fn contains(&self, a: u32, n: usize) -> bool {
        a >= self.base && (a - self.base) as usize + n <= self.len
    }
    fn slice(&self) -> &[u8] {
        // SAFETY: `ptr` is a leaked allocation of `len` bytes; the CPU
        // writes it only while the runner is inside unicorn, never while
        // the machine (which holds this) runs
        unsafe { std::slice::from_raw_parts(self.ptr, self.len) }
    }
    fn slice_mut(&mut self) -> &mut [u8] {
        // SAFETY: as in `slice`
        unsafe { std::slice::from_raw_parts_mut(self.ptr, self.len) }
    }
    /// Little-endian read of `n` (1, 2, 4) bytes at `a` (inside).
    pub fn read(&self, a: u32, n: usize) -> u32 {
        let o = (a - self.base) as usize;
        let mut b = [0u8; 4];
        b[..n].copy_from_slice(&self.slice()[o..o + n]);
        u32::from_le_bytes(b)
    }
    pub fn write(&mut self, a: u32, n: usize, v: u32) {
        let o = (a - self.base) as usize;
        self.slice_mut()[o..o + n].copy_from_slice(&v.to_le_bytes()[..n]);
    }
}

impl std::fmt::Debug for HostMem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "HostMem({:#010x}, {} bytes)", self.base, self.len)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_what_was_written_little_endian_and_knows_its_bounds() {
        let mut m = HostMem::new(0x2000_0000, 4096);
        m.write(0x2000_0010, 4, 0x1234_5678);
        assert_eq!(m.read(0x2000_0010, 2), 0x5678);
        assert_eq!(m.read(0x2000_0013, 1), 0x12);
        assert!(m.contains(0x2000_0FFC, 4));
        assert!(!m.contains(0x2000_0FFE, 4));
        assert!(!m.contains(0x1FFF_FFFF, 1));
    }
}
