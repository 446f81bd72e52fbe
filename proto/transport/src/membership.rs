//! Which publisher may speak for which actor id.
//!
//! A header's `actor_id` is whatever its writer put there; the publisher a
//! message came through is known to the receiving side. An actor joins with
//! a proof that it holds the run's key ([`proto::Join`]), which binds its id
//! to its three publishers; from then on only those publishers speak for it.
//! A restarted actor joins again from new publishers and replaces the old
//! binding; without the key nobody can bind an id, so ghosts and spoofers are
//! refused and counted. The same rule carries over to other hosts: a gateway
//! that forwards a host's actors joins each of them from its own publishers,
//! so a host speaks only for the actors that joined through it.
//!
//! Publishers that have not joined are screened before a byte of what they
//! sent is read ([`Membership::screen`]): the length a subscriber sees comes
//! from the publisher's side of shared memory, and iceoryx2 0.10 does not
//! check it against the segment the publisher mapped, so a foreign publisher
//! with a small segment and a lying length would make the learner read past
//! it (a crash, not just a refusal): the learner and the gateway on an actor
//! host both screen so. Only a join's exact length is read from
//! a stranger, on the stats service.

use std::collections::HashMap;

use proto::{Join, JoinKey, MessageKind};

/// What a join changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Joined {
    /// The id had no binding.
    New,
    /// The id was bound to other publishers (the actor restarted).
    Again,
    /// The same binding again (actors repeat their join).
    Unchanged,
}

/// Who sent a message that [`Membership::screen`] let through.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sender {
    /// A publisher that joined (or one an actor held before it restarted).
    Member,
    /// A publisher that has not joined; its message can only be a join.
    Stranger,
}

/// Bytes of a join message: the only message a publisher that has not
/// joined may send.
const JOIN_MESSAGE_LEN: usize = proto::HEADER_LEN + proto::JOIN_PAYLOAD_LEN;

/// Publishers an id held before its newest join that are still told apart
/// from strangers (a restarted actor's last messages may still be queued).
const REMEMBERED_BINDINGS: usize = 4;

/// The learner's record of joins.
pub struct Membership {
    key: JoinKey,
    members: HashMap<u32, [u128; 3]>,
    /// Per id, the publishers of its earlier joins, newest last.
    replaced: HashMap<u32, Vec<[u128; 3]>>,
}

impl Membership {
    /// No actor has joined yet; joins must prove `key`.
    pub fn new(key: JoinKey) -> Self {
        Self {
            key,
            members: HashMap::new(),
            replaced: HashMap::new(),
        }
    }

    /// Handles `join` for `actor_id` that arrived through `origin`; the error
    /// is the reason it is refused (a metrics label).
    pub fn join(
        &mut self,
        actor_id: u32,
        join: &Join,
        origin: u128,
    ) -> Result<Joined, &'static str> {
        if !join.verify(&self.key, actor_id) {
            return Err("bad_join_proof");
        }
        if join.publisher(MessageKind::Join) != Some(origin) {
            return Err("join_from_another_publisher");
        }
        Ok(match self.members.insert(actor_id, join.publishers) {
            None => Joined::New,
            Some(old) if old == join.publishers => Joined::Unchanged,
            Some(old) => {
                let earlier = self.replaced.entry(actor_id).or_default();
                earlier.push(old);
                if earlier.len() > REMEMBERED_BINDINGS {
                    earlier.remove(0);
                }
                Joined::Again
            }
        })
    }

    /// Whether a `len`-byte message on the service of `kind` that came
    /// through `origin` may be read at all: from a publisher that joined (or
    /// one an actor held before it restarted), anything the service allows;
    /// from any other, only a join, on the stats service, of a join's exact
    /// length. The error is the reason it is refused unread.
    pub fn screen(
        &self,
        kind: MessageKind,
        origin: u128,
        len: usize,
    ) -> Result<Sender, &'static str> {
        let joined = self
            .members
            .values()
            .chain(self.replaced.values().flatten())
            .any(|publishers| Join::publisher_for(publishers, kind) == Some(origin));
        if joined {
            Ok(Sender::Member)
        } else if kind == MessageKind::Stats && len == JOIN_MESSAGE_LEN {
            Ok(Sender::Stranger)
        } else {
            Err("unknown_publisher")
        }
    }

    /// Whether a `kind` message that says it is from `actor_id` and came
    /// through `origin` may be accepted; the error is the reason it is not.
    pub fn admit(
        &self,
        actor_id: u32,
        kind: MessageKind,
        origin: u128,
    ) -> Result<(), &'static str> {
        let Some(publishers) = self.members.get(&actor_id) else {
            return Err("not_joined");
        };
        if Join::publisher_for(publishers, kind) == Some(origin) {
            return Ok(());
        }
        let replaced = self.replaced.get(&actor_id).is_some_and(|earlier| {
            earlier
                .iter()
                .any(|p| Join::publisher_for(p, kind) == Some(origin))
        });
        // A message of the actor's previous life (it restarted and joined
        // again) is refused too, but not counted as a stranger's.
        Err(if replaced {
            "from_a_replaced_publisher"
        } else {
            "not_its_publisher"
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(byte: u8) -> JoinKey {
        JoinKey::from_bytes([byte; proto::JOIN_KEY_LEN])
    }

    #[test]
    fn only_the_publishers_that_joined_speak_for_an_id() {
        let mut members = Membership::new(key(1));
        assert_eq!(members.admit(0, MessageKind::Stats, 12), Err("not_joined"));
        let join = Join::new(&key(1), 0, [10, 11, 12]);
        assert_eq!(members.join(0, &join, 12), Ok(Joined::New));
        assert_eq!(members.join(0, &join, 12), Ok(Joined::Unchanged));
        assert_eq!(members.admit(0, MessageKind::Rollout, 10), Ok(()));
        assert_eq!(members.admit(0, MessageKind::Frames, 11), Ok(()));
        assert_eq!(members.admit(0, MessageKind::Stats, 12), Ok(()));
        assert_eq!(
            members.admit(0, MessageKind::Rollout, 12),
            Err("not_its_publisher"),
            "each kind through its own publisher"
        );
        assert_eq!(
            members.admit(0, MessageKind::Stats, 99),
            Err("not_its_publisher")
        );
        assert_eq!(members.admit(7, MessageKind::Stats, 12), Err("not_joined"));
    }

    #[test]
    fn strangers_are_read_only_for_a_join_of_the_join_length() {
        let mut members = Membership::new(key(1));
        let join = Join::new(&key(1), 0, [10, 11, 12]);
        let join_len = proto::encode(&join, proto::MessageHeader::default()).len();
        assert_eq!(
            members.screen(MessageKind::Stats, 12, join_len),
            Ok(Sender::Stranger)
        );
        for len in [0, join_len - 1, join_len + 1, 4096] {
            assert_eq!(
                members.screen(MessageKind::Stats, 12, len),
                Err("unknown_publisher")
            );
        }
        assert_eq!(
            members.screen(MessageKind::Rollout, 10, join_len),
            Err("unknown_publisher"),
            "no join comes on the rollouts service"
        );
        members.join(0, &join, 12).unwrap();
        assert_eq!(
            members.screen(MessageKind::Rollout, 10, 1 << 20),
            Ok(Sender::Member)
        );
        assert_eq!(
            members.screen(MessageKind::Frames, 11, 1 << 20),
            Ok(Sender::Member)
        );
        assert_eq!(
            members.screen(MessageKind::Stats, 12, join_len),
            Ok(Sender::Member)
        );
        assert_eq!(
            members.screen(MessageKind::Stats, 12, 300),
            Ok(Sender::Member)
        );
        assert_eq!(
            members.screen(MessageKind::Rollout, 11, 1 << 20),
            Err("unknown_publisher"),
            "a member's frames publisher does not speak on the rollouts service"
        );
        assert_eq!(
            members.screen(MessageKind::Rollout, 99, 1 << 20),
            Err("unknown_publisher")
        );
        members
            .join(0, &Join::new(&key(1), 0, [30, 31, 32]), 32)
            .unwrap();
        assert_eq!(
            members.screen(MessageKind::Rollout, 10, 1 << 20),
            Ok(Sender::Member),
            "a restarted actor's queued messages are still read (and refused by admit)"
        );
    }

    #[test]
    fn joins_without_the_key_or_through_another_publisher_are_refused() {
        let mut members = Membership::new(key(1));
        let forged = Join::new(&key(2), 0, [20, 21, 22]);
        assert_eq!(members.join(0, &forged, 22), Err("bad_join_proof"));
        let real = Join::new(&key(1), 0, [10, 11, 12]);
        assert_eq!(
            members.join(0, &real, 22),
            Err("join_from_another_publisher"),
            "a replayed join"
        );
        assert_eq!(
            members.join(3, &real, 12),
            Err("bad_join_proof"),
            "made for actor 0"
        );
        assert_eq!(members.admit(0, MessageKind::Stats, 22), Err("not_joined"));
    }

    #[test]
    fn a_restarted_actor_replaces_its_old_publishers() {
        let mut members = Membership::new(key(1));
        members
            .join(0, &Join::new(&key(1), 0, [10, 11, 12]), 12)
            .unwrap();
        let again = Join::new(&key(1), 0, [30, 31, 32]);
        assert_eq!(members.join(0, &again, 32), Ok(Joined::Again));
        assert_eq!(members.admit(0, MessageKind::Rollout, 30), Ok(()));
        assert_eq!(
            members.admit(0, MessageKind::Rollout, 10),
            Err("from_a_replaced_publisher"),
            "the previous life's queued messages are told apart from a stranger's"
        );
        assert_eq!(
            members.admit(0, MessageKind::Rollout, 99),
            Err("not_its_publisher")
        );
        for restart in 0..10u128 {
            let p = 100 + 3 * restart;
            members
                .join(0, &Join::new(&key(1), 0, [p, p + 1, p + 2]), p + 2)
                .unwrap();
        }
        assert_eq!(
            members.admit(0, MessageKind::Rollout, 10),
            Err("not_its_publisher"),
            "only the last few lives are remembered"
        );
    }
}
