//! ④ Agent: the action component and the policies that write it.
