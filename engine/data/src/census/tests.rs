use super::*;

#[test]
fn spread_keeps_the_first_and_at_most_n() {
    let items: Vec<usize> = (10..100).collect();
    let s = spread(&items, 24);
    assert_eq!(s.len(), 24);
    assert_eq!(s[0], 10);
    assert!(s.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(spread(&items[..3], 24), vec![10, 11, 12]);
    assert!(spread(&[], 24).is_empty());
}

#[test]
fn shares_of_no_person_are_zero() {
    let p = PartPixels::default();
    assert_eq!(p.share(p.hands()), 0.0);
    let p = PartPixels {
        person: 200.0,
        left_hand: 3.0,
        right_hand: 1.0,
        ..PartPixels::default()
    };
    assert_eq!(p.share(p.hands()), 0.02);
}
