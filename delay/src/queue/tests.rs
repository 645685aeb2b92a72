use super::*;

#[test]
fn ties_leave_in_push_order() {
    let mut q = ReleaseQueue::new();
    q.push(5, "b");
    q.push(3, "a");
    q.push(5, "c");
    assert_eq!(q.pop_due(2), None);
    assert_eq!(q.pop_due(5), Some((3, "a")));
    assert_eq!(q.pop_due(5), Some((5, "b")));
    assert_eq!(q.drain(), vec![(5, "c")]);
    assert!(q.is_empty());
}
